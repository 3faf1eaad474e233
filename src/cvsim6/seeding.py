"""Seeds of the project's independent random streams, derived from one master seed.

Pure functions of integers (NumPy's ``SeedSequence``): the same master seed gives the same
streams on every machine. Training, NPE and the studies draw their streams from here.
"""
from __future__ import annotations

import numpy as np


def derived_seed(seed: int, stream: int) -> int:
    """Independent 63-bit seed for random stream ``stream`` of master ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(stream)]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def candidate_seed(seed: int, candidate: int) -> int:
    """Seed of restart candidate ``candidate`` (initial weights and training stream): ``seed``
    itself for candidate 0, so that a run with restarts in which candidate 0 wins continues
    exactly as the run without restarts; independent derived seeds for the others."""
    return int(seed) if candidate == 0 else derived_seed(seed, 1000 + int(candidate))
