"""Uniform priors over the 23 parameters, as multipliers of the registry defaults.

A prior specification is a mapping with a ``default`` multiplier interval, optional
``kinds`` (per parameter kind: ``compliance``, ``resistance``, ``volume``, ``rate``,
``pressure``, ``ratio``) and optional per-parameter ``parameters`` overrides; the
most specific entry wins. Bounds are in clinical units; for the negative ``P_th``
the interval is ordered (multipliers [0.7, 1.3] give [-5.2, -2.8] mmHg).
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cvsim6.registry import PARAMETER_NAMES, PARAMETERS

#: The two priors of the paper (facts page: "Priors").
PAPER_PRIORS: dict[str, dict] = {
    "structural": {"default": [0.7, 1.3], "kinds": {"compliance": [0.5, 1.5]}},
    "ehr": {
        "default": [0.7, 1.3],
        "kinds": {"compliance": [0.2, 1.6], "resistance": [0.2, 1.6]},
        "parameters": {"Hr": [0.8, 1.6]},
    },
}


def prior_bounds(spec: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (clinical units, registry order) of a prior spec."""
    kinds = spec.get("kinds", {}) or {}
    per = spec.get("parameters", {}) or {}
    unknown = set(per) - set(PARAMETER_NAMES)
    if unknown:
        raise ValueError(f"prior names unknown parameter(s): {', '.join(sorted(unknown))}")
    lo, hi = np.empty(len(PARAMETERS)), np.empty(len(PARAMETERS))
    for i, p in enumerate(PARAMETERS):
        m = per.get(p.name, kinds.get(p.kind, spec["default"]))
        m0, m1 = float(m[0]), float(m[1])
        if not m0 <= m1:
            raise ValueError(f"prior for {p.name}: multipliers {m0} > {m1}")
        a, b = m0 * p.default, m1 * p.default
        lo[i], hi[i] = min(a, b), max(a, b)
    return lo, hi


def sample_uniform(lo: np.ndarray, hi: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` independent uniform draws, shape (n, 23), from one generator stream."""
    u = rng.random((n, len(lo)))
    return lo + (hi - lo) * u
