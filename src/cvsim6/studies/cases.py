"""Held-out simulated cases shared by the calibration and the reference-posterior studies.

The cases are rows of the EHR study's simulated validation split, picked with a seed, and
their noisy observations y' = y + eta(delta) in physical units (registry units). The rows
and the standard-normal noise draw are the same at every noise level delta; only its scale
changes. This module imports neither sbi nor the MCMC sampler, so that a change to one
method's code reruns that method's results only.
"""
from __future__ import annotations

import numpy as np
import torch

from cvsim6 import nets as nw
from cvsim6.data.datasets import load_split


def calibration_cases(validation: str, n_cases: int, noise_level: float, seed: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n_cases`` validation rows picked with ``seed`` (the same for every noise level):
    true parameters (n, 23), clean outputs (n, 16) and noisy observations (n, 16)."""
    v, y = load_split(validation)
    if not 1 <= int(n_cases) <= len(v):
        raise ValueError(f"n_cases = {n_cases} must be between 1 and the {len(v)} validation rows")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 31]))
    pick = np.sort(rng.choice(len(v), size=int(n_cases), replace=False))
    gen = torch.Generator().manual_seed(int(np.random.SeedSequence([int(seed), 37]).generate_state(1)[0]))
    unit_noise = nw.draw_noise(len(pick), 1.0, gen).numpy()  # delta = 1: noise std s
    return v[pick], y[pick], y[pick] + float(noise_level) * unit_noise
