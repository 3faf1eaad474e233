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
1st percentile is less likely under the model than 99% of simulated patients; with n
reference outputs the percentile moves in steps of 100/n.

Units: physical (registry) units in and out; the networks standardize internally.
"""
from __future__ import annotations

import numpy as np
import torch

from cvsim6.nets import DEFAULT_CORRECTOR_STEPS
from cvsim6.registry import N_OUTPUTS


def seeded_torch_generator(seed: int) -> torch.Generator:
    """A CPU ``torch.Generator`` seeded with ``seed``: the random stream of every draw here."""
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
    y_obs = np.asarray(y_obs, float).reshape(1, N_OUTPUTS)
    return complete_missing_shared(flow, y_obs, n_samples, top_k=top_k, seed=seed, chunk_size=chunk_size)[0]


@torch.no_grad()
def complete_missing_shared(flow, y_obs: np.ndarray, n_samples: int, top_k: int = 1, seed: int = 0,
                            chunk_size: int = 25 * SAMPLE_BLOCK,
                            progress: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """Algorithm 1 for every row of ``y_obs`` (n, 16), NaN = missing, all rows ranking the same
    ``n_samples`` flow samples: each chunk of samples is drawn once and completed by every row.

    Returns one ``(completions (top_k, 16), log-densities (top_k,))`` per row, as
    :func:`complete_missing` gives for that row alone with the same ``seed`` (the same numbers:
    each row's log-densities are computed on the same chunks). Drawing is half the cost of
    ranking one sample, so sharing it halves the CPU time per row. ``progress``: a bar over chunks.
    """
    y_obs = np.asarray(y_obs, float).reshape(-1, N_OUTPUTS)
    missing = ~np.isfinite(y_obs)
    out: list = [None] * len(y_obs)
    for i in np.flatnonzero(~missing.any(axis=1)):
        out[i] = (y_obs[i][None].copy(), np.asarray(flow.log_prob_physical(y_obs[i][None]), float).reshape(1))
    rows = np.flatnonzero(missing.any(axis=1))
    if len(rows) == 0:
        return out
    flow.eval()
    n_samples, top_k = int(n_samples), int(top_k)
    n_blocks = -(-n_samples // SAMPLE_BLOCK)
    per_chunk = max(1, int(chunk_size) // SAMPLE_BLOCK)
    best = {i: (np.empty((0, N_OUTPUTS)), np.empty(0), np.empty(0, dtype=np.int64)) for i in rows}
    starts = range(0, n_blocks, per_chunk)
    if progress:
        from tqdm import tqdm

        starts = tqdm(starts, unit="chunk", desc=f"Algorithm 1, {len(rows)} rows x {n_samples} samples")
    for b0 in starts:
        samples = np.vstack([
            flow.sample_physical(min(SAMPLE_BLOCK, n_samples - b * SAMPLE_BLOCK),
                                 generator=seeded_torch_generator(_block_seed(seed, b)))
            for b in range(b0, min(n_blocks, b0 + per_chunk))])
        idx = np.arange(b0 * SAMPLE_BLOCK, b0 * SAMPLE_BLOCK + len(samples))
        for i in rows:
            y = samples.copy()
            y[:, ~missing[i]] = y_obs[i, ~missing[i]]
            lp = np.asarray(flow.log_prob_physical(y), float)
            lp[~np.isfinite(lp)] = -np.inf
            best[i] = _merge_top_k(best[i], (y, lp, idx), top_k)
    for i in rows:
        out[i] = best[i][:2]
    return out


def _merge_top_k(best: tuple, new: tuple, top_k: int) -> tuple:
    """The ``top_k`` of two ``(rows, log p, sample index)`` sets, by (-log p, sample index):
    the new set is cut to its candidates (log p at or above its k-th largest) before sorting."""
    y, lp, idx = new
    if len(lp) > top_k:
        keep = lp >= np.partition(lp, len(lp) - top_k)[len(lp) - top_k]
        y, lp, idx = y[keep], lp[keep], idx[keep]
    cy, cl, ci = np.vstack([best[0], y]), np.concatenate([best[1], lp]), np.concatenate([best[2], idx])
    order = np.lexsort((ci, -cl))[:top_k]
    return cy[order], cl[order], ci[order]


def decode_latent(encdec, y: np.ndarray, n_latent: int, seed: int = 0,
                  corrector_steps: int = DEFAULT_CORRECTOR_STEPS) -> np.ndarray:
    """Decode each output row (n, 16) with ``n_latent`` draws w ~ N(0, I) and
    ``corrector_steps`` predictor-corrector rounds (see ``EncoderDecoder.invert``).

    Returns parameters of shape (n, n_latent, 23), physical units.
    """
    y = np.atleast_2d(np.asarray(y, float))
    w = torch.randn(len(y) * n_latent, encdec.latent_dim, generator=seeded_torch_generator(seed),
                    dtype=torch.float64)
    v = encdec.invert(np.repeat(y, n_latent, axis=0), w.numpy(), corrector_steps=corrector_steps)
    return np.asarray(v).reshape(len(y), n_latent, -1)


def ood_percentile(score: float, reference_scores: np.ndarray) -> float:
    """Percentage of the finite reference scores below ``score`` (0 = less likely than all).

    Its resolution is 100/n percentage points for n finite reference scores: with n = 100,
    0 means "below the 1st percentile", nothing finer (report n beside it).
    """
    ref = np.asarray(reference_scores, float)
    ref = ref[np.isfinite(ref)]
    if len(ref) == 0:
        return float("nan")
    return 100.0 * float((ref < score).mean())


@torch.no_grad()
def reference_scores(flow, y_simulated: np.ndarray, missing: np.ndarray, n_samples: int,
                     seed: int = 0, max_rows_per_pass: int = 65536) -> np.ndarray:
    """The Algorithm-1 best log-density of each simulated output row with ``missing`` entries
    hidden: row i scores ``complete_missing(flow, row_i, n_samples, seed=seed)[1][0]``.

    All rows are completed by the same ``n_samples`` flow samples, drawn once (up to
    25 blocks of :data:`SAMPLE_BLOCK`; beyond that in chunks, :func:`complete_missing_shared`).
    A non-finite density counts as -inf.
    """
    y = np.asarray(y_simulated, float).reshape(-1, N_OUTPUTS)
    missing = np.asarray(missing, bool).reshape(N_OUTPUTS)
    flow.eval()
    if not missing.any():
        lp = np.asarray(flow.log_prob_physical(y), float)
        lp[~np.isfinite(lp)] = -np.inf
        return lp
    n_samples = int(n_samples)
    n_blocks = -(-n_samples // SAMPLE_BLOCK)
    if n_blocks > 25:
        done = complete_missing_shared(flow, np.where(missing, np.nan, y), n_samples, seed=seed)
        return np.array([lp[0] for _, lp in done])
    samples = np.vstack([flow.sample_physical(min(SAMPLE_BLOCK, n_samples - b * SAMPLE_BLOCK),
                                              generator=seeded_torch_generator(_block_seed(seed, b)))
                         for b in range(n_blocks)])
    per_pass = max(1, int(max_rows_per_pass) // len(samples))
    out = np.empty(len(y))
    for i0 in range(0, len(y), per_pass):
        part = y[i0:i0 + per_pass]
        comp = np.repeat(samples[None], len(part), axis=0)  # (rows, n_samples, 16)
        comp[:, :, ~missing] = part[:, None, ~missing]
        lp = np.asarray(flow.log_prob_physical(comp.reshape(-1, N_OUTPUTS)), float).reshape(len(part), -1)
        lp[~np.isfinite(lp)] = -np.inf
        out[i0:i0 + len(part)] = lp.max(axis=1)
    return out
