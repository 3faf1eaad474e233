"""Calibration diagnostics of an inverse model on simulated cases with known parameters.

For n held-out cases with true parameters theta_i (n, d) and N parameter samples per
case (n, N, d) from an inverse method (inVAErt's decoded sets or an NPE posterior):

* *SBC ranks* (Talts et al. 2018): rank of theta_ij among the N samples of parameter j;
  for a calibrated posterior the ranks are uniform on {0..N}. Uniformity is tested with
  sbi's Kolmogorov-Smirnov check (``sbi.diagnostics.sbc.check_uniformity_frequentist``).
* *Expected coverage* of central credible intervals: at nominal level a, the fraction of
  cases whose theta_ij lies between the (1-a)/2 and (1+a)/2 sample quantiles; the
  *coverage error* is the mean |empirical - nominal| over the levels.
* *TARP* (Lemos et al. 2023), a joint coverage test over all d parameters, scaled to the
  prior box (sbi's ``_run_tarp`` and ``check_tarp``): the ATC is 0 for a calibrated
  sampler, < 0 for an over-confident one, > 0 for an under-confident one.
* *Contraction* 1 - Var_post / Var_prior per parameter (0: the data taught nothing,
  1: a point), with the prior variance of a uniform prior, width^2 / 12.
* *NRMSE* of the posterior mean: RMS(mean_i - theta_i) / prior standard deviation.

Every function takes arrays in physical units; the diagnostics themselves are unitless.
"""
from __future__ import annotations

import numpy as np
import torch
from sbi.diagnostics.sbc import check_uniformity_frequentist
from sbi.diagnostics.tarp import _run_tarp, check_tarp

#: Nominal levels of the central credible intervals in the coverage curves.
COVERAGE_LEVELS = np.round(np.arange(0.05, 0.96, 0.05), 2)


def _check_shapes(theta: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    theta = np.asarray(theta, float)
    samples = np.asarray(samples, float)
    if theta.ndim != 2 or samples.ndim != 3 or samples.shape[0] != theta.shape[0] \
            or samples.shape[2] != theta.shape[1]:
        raise ValueError(f"expected theta (n, d) and samples (n, N, d); got {theta.shape} and {samples.shape}")
    return theta, samples


def sbc_ranks(theta: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Rank of each true value among its samples: the count of samples below it, (n, d) in 0..N."""
    theta, samples = _check_shapes(theta, samples)
    return (samples < theta[:, None, :]).sum(axis=1)


def sbc_pvalues(ranks: np.ndarray, n_samples: int) -> np.ndarray:
    """KS p-value of the uniformity of each parameter's ranks (d,) (sbi's check)."""
    r = torch.as_tensor(np.asarray(ranks, float), dtype=torch.float32)
    return check_uniformity_frequentist(r, int(n_samples)).numpy().astype(float)


def coverage(theta: np.ndarray, samples: np.ndarray, levels: np.ndarray = COVERAGE_LEVELS) -> np.ndarray:
    """Empirical coverage of central credible intervals, (len(levels), d): the fraction of
    cases whose true value lies in the interval between the sample quantiles (1 -+ a) / 2."""
    theta, samples = _check_shapes(theta, samples)
    levels = np.asarray(levels, float)
    lo = np.quantile(samples, (1 - levels) / 2, axis=1)  # (L, n, d)
    hi = np.quantile(samples, (1 + levels) / 2, axis=1)
    inside = (lo <= theta[None]) & (theta[None] <= hi)
    return inside.mean(axis=1)


def coverage_error(cov: np.ndarray, levels: np.ndarray = COVERAGE_LEVELS) -> np.ndarray:
    """Mean |empirical - nominal| coverage over the levels, per parameter (d,)."""
    return np.abs(np.asarray(cov, float) - np.asarray(levels, float)[:, None]).mean(axis=0)


def contraction(samples: np.ndarray, prior_lo: np.ndarray, prior_hi: np.ndarray) -> np.ndarray:
    """Mean over cases of 1 - Var_post / Var_prior per parameter (d,); uniform prior on [lo, hi]."""
    prior_var = (np.asarray(prior_hi, float) - np.asarray(prior_lo, float)) ** 2 / 12.0
    return (1.0 - np.asarray(samples, float).var(axis=1) / prior_var).mean(axis=0)


def nrmse(theta: np.ndarray, samples: np.ndarray, prior_lo: np.ndarray, prior_hi: np.ndarray) -> np.ndarray:
    """RMS error of the posterior mean over cases, in prior standard deviations, per parameter (d,)."""
    theta, samples = _check_shapes(theta, samples)
    prior_std = (np.asarray(prior_hi, float) - np.asarray(prior_lo, float)) / np.sqrt(12.0)
    return np.sqrt(((samples.mean(axis=1) - theta) ** 2).mean(axis=0)) / prior_std


def tarp(theta: np.ndarray, samples: np.ndarray, prior_lo: np.ndarray, prior_hi: np.ndarray,
         seed: int = 0, num_bins: int | None = None) -> dict:
    """TARP over all parameters, scaled to the prior box [0, 1]^d, with reference points
    drawn uniformly in the box (seeded). Returns ``alpha`` and ``ecp`` (the curve), ``atc``
    (area to the diagonal above alpha = 0.5) and ``ks_pvalue`` (sbi's ``check_tarp``)."""
    theta, samples = _check_shapes(theta, samples)
    lo, hi = np.asarray(prior_lo, float), np.asarray(prior_hi, float)
    unit = lambda a: torch.as_tensor((a - lo) / (hi - lo), dtype=torch.float32)  # noqa: E731
    refs = torch.rand(theta.shape, generator=torch.Generator().manual_seed(int(seed)))
    ecp, alpha = _run_tarp(unit(samples).transpose(0, 1), unit(theta), refs, num_bins=num_bins)
    atc, ks = check_tarp(ecp, alpha)
    return dict(alpha=alpha.numpy().astype(float), ecp=ecp.numpy().astype(float), atc=float(atc),
                ks_pvalue=float(ks))


def diagnostics(theta: np.ndarray, samples: np.ndarray, prior_lo: np.ndarray, prior_hi: np.ndarray,
                levels: np.ndarray = COVERAGE_LEVELS) -> dict[str, np.ndarray]:
    """Every per-parameter diagnostic, (d,) each: ``sbc_pvalue``, ``coverage_error``,
    ``contraction``, ``nrmse``; and ``coverage`` (len(levels), d), ``ranks`` (n, d)."""
    theta, samples = _check_shapes(theta, samples)
    ranks = sbc_ranks(theta, samples)
    cov = coverage(theta, samples, levels)
    return dict(sbc_pvalue=sbc_pvalues(ranks, samples.shape[1]), coverage_error=coverage_error(cov, levels),
                contraction=contraction(samples, prior_lo, prior_hi),
                nrmse=nrmse(theta, samples, prior_lo, prior_hi), coverage=cov, ranks=ranks)
