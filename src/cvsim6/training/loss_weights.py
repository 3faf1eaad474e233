"""Weightings of the emulator's squared errors (hyperparameters ``variance_floor`` and
``relative_weight``; the schema describes both): a matrix on the errors, weights on the rows."""
from __future__ import annotations

import numpy as np


def variance_floor_matrix(y_std: np.ndarray, floor: float) -> np.ndarray:
    """Symmetric ``W = V diag(sqrt(max(1, floor/lam))) V^T`` (n_out, n_out), with ``lam, V`` the
    eigenvalues and vectors of the covariance ``C`` of the standardized outputs ``y_std`` (N,
    n_out): ``W C W`` has the eigenvalues ``max(lam, floor)``. An error ``e`` (row) in standardized
    units is ``e @ W`` as the loss sees it: unchanged along directions of variance >= floor,
    scaled up along the smaller ones."""
    y = np.asarray(y_std, dtype=np.float64)
    lam, vec = np.linalg.eigh(np.cov(y, rowvar=False))
    if not np.all(lam > 0):
        raise ValueError(f"variance floor: the output covariance is singular (eigenvalue {lam.min():.3g})")
    return (vec * np.sqrt(np.maximum(1.0, float(floor) / lam))) @ vec.T


def relative_sample_weights(y_train: np.ndarray, y: np.ndarray, relative_weight: float) -> np.ndarray:
    """Row weights (N,) ``(1 - a) + a * (1/|y_i|^2) / mean_j(1/|y_train_j|^2)`` for the physical
    outputs ``y`` (N, n_out), ``|.|`` the Euclidean norm over the outputs and the mean over the
    rows of ``y_train``: they average 1 over ``y_train``; ``a = 0`` gives ones. Raises
    ``ValueError`` naming the first row whose norm is zero or not finite."""
    norms2 = {name: np.sum(np.asarray(a, np.float64) ** 2, axis=1) for name, a in (("training", y_train), ("given", y))}
    for name, n2 in norms2.items():
        bad = np.flatnonzero(~(np.isfinite(n2) & (n2 > 0)))
        if bad.size:
            raise ValueError(f"relative weights: row {bad[0]} of the {name} outputs has the squared norm {float(n2[bad[0]])!r}")
    a = float(relative_weight)
    return (1.0 - a) + a * (1.0 / norms2["given"]) / np.mean(1.0 / norms2["training"])
