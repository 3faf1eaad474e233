"""Identifiability diagnostics: manifold SVD and a local, Jacobian-based check.

*Manifold SVD* (paper section 3.3.2): singular values of a matrix of parameter sets
sampled from a non-identifiable manifold, their cumulative energy
``CE_n = sum_{k<=n} s_k^2 / sum_k s_k^2`` and the number of modes reaching a level.

*Local check* (beyond the paper): at a parameter set v, the Jacobian ``J = dy/dv`` of
the simulator's 16 outputs (central finite differences on the batch path) made
dimensionless as ``J~ = diag(1/s) J diag(w)``, with ``s`` the outputs' measurement
noise std (registry) and ``w`` the prior widths. Its numerical rank r is the number
of locally identifiable parameter combinations; ``23 - r`` is the local dimension of
the non-identifiable manifold through v. A parameter's *null-space share* is
``||N_j||^2 / (23 - r)`` for an orthonormal null-space basis N: 0 for a locally
identifiable parameter, larger the more freely it moves along the manifold.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cvsim6.registry import noise_std
from cvsim6.model.solver import simulate_batch


def cumulative_energy(singular_values: np.ndarray) -> np.ndarray:
    """Cumulative energy of singular values (fraction in [0, 1]); all ones for a zero matrix
    (nothing to reconstruct)."""
    e = np.asarray(singular_values, float) ** 2
    total = e.sum()
    return np.cumsum(e) / total if total > 0 else np.ones_like(e)


def modes_for_energy(singular_values: np.ndarray, level: float = 0.99) -> tuple[int, float]:
    """Smallest number of modes whose cumulative energy reaches ``level``, and that energy
    (``(0, 1.0)`` for a zero matrix, e.g. samples that do not vary at all)."""
    s = np.asarray(singular_values, float)
    if not (s**2).sum() > 0:
        return 0, 1.0
    ce = cumulative_energy(s)
    n = int(np.searchsorted(ce, level - 1e-15) + 1)
    return n, float(ce[n - 1])


def manifold_svd(samples: np.ndarray, scaling: str = "standardize") -> np.ndarray:
    """Singular values of the (n, d) matrix of manifold samples.

    ``scaling="standardize"`` (the paper's code: scikit-learn's StandardScaler) centres each
    column and divides it by its standard deviation, so that the count of modes does not
    depend on the parameters' units; ``"none"`` takes the raw matrix. Constant columns stay 0.
    """
    X = np.asarray(samples, float)
    if scaling == "standardize":
        X = X - X.mean(axis=0)
        sd = X.std(axis=0)
        X = X / np.where(sd > 0, sd, 1.0)
    elif scaling != "none":
        raise ValueError(f"scaling must be 'standardize' or 'none', got {scaling!r}")
    return np.linalg.svd(X, compute_uv=False)


def finite_difference_jacobian(
    f: Callable[[np.ndarray], np.ndarray], v: np.ndarray, widths: np.ndarray, rel_step: float = 1e-4
) -> np.ndarray:
    """Central-difference Jacobians of ``f`` at each row of ``v`` (N, d) -> (N, m, d).

    Parameter j is perturbed by ``rel_step * widths[j]``; ``f`` maps an (M, d) array to
    (M, m) and is called once on all 2 d N perturbed points (a single batch).
    """
    v = np.atleast_2d(np.asarray(v, float))
    n, d = v.shape
    h = rel_step * np.asarray(widths, float)
    pts = np.repeat(v[:, None, None, :], 2, axis=1).repeat(d, axis=2)  # (n, 2, d, d)
    idx = np.arange(d)
    pts[:, 0, idx, idx] += h
    pts[:, 1, idx, idx] -= h
    y = np.asarray(f(pts.reshape(-1, d)), float).reshape(n, 2, d, -1)
    return np.transpose((y[:, 0] - y[:, 1]) / (2 * h[None, :, None]), (0, 2, 1))


def scaled_jacobian(J: np.ndarray, widths: np.ndarray, output_scale: np.ndarray | None = None) -> np.ndarray:
    """``diag(1/s) J diag(w)``: outputs in units of noise std, parameters in prior widths."""
    s = noise_std() if output_scale is None else np.asarray(output_scale, float)
    return J * np.asarray(widths, float)[None, None, :] / s[None, :, None]


def numerical_rank(singular_values: np.ndarray, rtol: float) -> int:
    """Number of singular values above ``rtol`` times the largest."""
    sv = np.asarray(singular_values, float)
    return int((sv > rtol * sv.max()).sum())


def local_identifiability(Js: np.ndarray, rtol: float = 1e-3):
    """Singular values, ranks and null-space shares of scaled Jacobians (N, m, d).

    Returns ``(singular_values (N, min(m, d)), ranks (N,), shares (N, d))`` where
    ``shares[i, j]`` is parameter j's share of the null space at point i (rows sum to
    1; all zero where the Jacobian has full column rank).
    """
    Js = np.asarray(Js, float)
    n, m, d = Js.shape
    svals = np.empty((n, min(m, d)))
    ranks = np.empty(n, dtype=int)
    shares = np.zeros((n, d))
    for i in range(n):
        _, s, vt = np.linalg.svd(Js[i], full_matrices=True)
        svals[i] = s
        r = numerical_rank(s, rtol)
        ranks[i] = r
        null = vt[r:]  # (d - r, d), orthonormal rows
        if len(null):
            shares[i] = (null**2).sum(axis=0) / len(null)
    return svals, ranks, shares


def simulator_outputs(steps_per_cycle: int = 600) -> Callable[[np.ndarray], np.ndarray]:
    """``f(v) -> y`` on the batch path (NaN rows where the simulator flags a set or a set
    lies outside the model's domain, e.g. a finite-difference step past a bound)."""
    def f(v: np.ndarray) -> np.ndarray:
        out, st = simulate_batch(v, steps_per_cycle=steps_per_cycle, invalid="flag")
        out[st != 0] = np.nan
        return out

    return f
