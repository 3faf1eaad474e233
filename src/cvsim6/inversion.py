"""Amortized inversion with a trained inVAErt network, and inversion with missing data.

*Algorithm 1* (paper section 3.3.3): draw M outputs from the density estimator NN_f,
overwrite the observed entries with the observation, rank the completed vectors by
their NN_f log-density and keep the most likely; decode each kept completion with
N_w latent draws ``w ~ N(0, I)`` through NN_d. The M samples are processed in chunks
that keep only the running top-k, so memory stays bounded whatever M; the ranking is
the same as in one pass (ties broken by sample index).

*Out-of-distribution score* (beyond the paper): the log-density of the best
completion of an observation, ranked against the same statistic on simulated
outputs with the same entries missing: its percentile among them. A patient at the
1st percentile is less likely under the model than 99% of simulated patients.

Units: physical (registry) units in and out; the networks standardize internally.
"""
from __future__ import annotations

import numpy as np
import torch

from .registry import N_OUTPUTS


def _generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed))


#: Flow samples are drawn in blocks of this size, block b from its own seeded
#: generator, so the sample stream does not depend on the chunk size.
SAMPLE_BLOCK = 4096


def _block_seed(seed: int, block: int) -> int:
    return int(np.random.SeedSequence([int(seed), int(block)]).generate_state(1)[0])


@torch.no_grad()
def complete_missing(flow, y_obs: np.ndarray, n_samples: int, top_k: int = 1, seed: int = 0,
                     chunk_size: int = 25 * SAMPLE_BLOCK) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 1, steps 1-4, for one observation ``y_obs`` (16,) with NaN = missing.

    Returns the ``top_k`` most likely completions (top_k, 16), physical units, and
    their log-densities (top_k,), best first. With nothing missing, returns y_obs.
    ``chunk_size`` (rounded to whole blocks) bounds memory; results do not depend on it.
    """
    y_obs = np.asarray(y_obs, float).reshape(N_OUTPUTS)
    missing = ~np.isfinite(y_obs)
    if not missing.any():
        lp = flow.log_prob_physical(y_obs[None])
        return y_obs[None].copy(), np.asarray(lp, float).reshape(1)
    flow.eval()
    n_samples = int(n_samples)
    n_blocks = -(-n_samples // SAMPLE_BLOCK)
    per_chunk = max(1, int(chunk_size) // SAMPLE_BLOCK)
    best_y = np.empty((0, N_OUTPUTS))
    best_lp = np.empty(0)
    best_idx = np.empty(0, dtype=np.int64)
    for b0 in range(0, n_blocks, per_chunk):
        parts = []
        for b in range(b0, min(n_blocks, b0 + per_chunk)):
            n = min(SAMPLE_BLOCK, n_samples - b * SAMPLE_BLOCK)
            parts.append(flow.sample_physical(n, generator=_generator(_block_seed(seed, b))))
        y = np.vstack(parts)
        y[:, ~missing] = y_obs[~missing]
        lp = np.asarray(flow.log_prob_physical(y), float)
        lp[~np.isfinite(lp)] = -np.inf
        idx = np.arange(b0 * SAMPLE_BLOCK, b0 * SAMPLE_BLOCK + len(y))
        # merge with the running top-k: sort by (-log p, sample index)
        cy = np.vstack([best_y, y])
        cl = np.concatenate([best_lp, lp])
        ci = np.concatenate([best_idx, idx])
        order = np.lexsort((ci, -cl))[:top_k]
        best_y, best_lp, best_idx = cy[order], cl[order], ci[order]
    return best_y, best_lp


def decode_latent(encdec, y: np.ndarray, n_latent: int, seed: int = 0, corrector_steps: int = 0) -> np.ndarray:
    """Decode each output row (n, 16) with ``n_latent`` draws w ~ N(0, I) and
    ``corrector_steps`` predictor-corrector rounds (see ``EncoderDecoder.invert``).

    Returns parameters of shape (n, n_latent, 23), physical units.
    """
    y = np.atleast_2d(np.asarray(y, float))
    w = torch.randn(len(y) * n_latent, encdec.latent_dim, generator=_generator(seed), dtype=torch.float64)
    v = encdec.invert(np.repeat(y, n_latent, axis=0), w.numpy(), corrector_steps=corrector_steps)
    return np.asarray(v).reshape(len(y), n_latent, -1)


def ood_percentile(score: float, reference_scores: np.ndarray) -> float:
    """Percentage of reference scores below ``score`` (0 = less likely than all)."""
    ref = np.asarray(reference_scores, float)
    ref = ref[np.isfinite(ref)]
    if len(ref) == 0:
        return float("nan")
    return 100.0 * float((ref < score).mean())


def reference_scores(flow, y_simulated: np.ndarray, missing: np.ndarray, n_samples: int,
                     seed: int = 0) -> np.ndarray:
    """The Algorithm-1 best log-density of simulated outputs with ``missing`` entries hidden."""
    out = np.empty(len(y_simulated))
    for i, y in enumerate(np.asarray(y_simulated, float)):
        yo = y.copy()
        yo[missing] = np.nan
        out[i] = complete_missing(flow, yo, n_samples, top_k=1, seed=seed + i)[1][0]
    return out
