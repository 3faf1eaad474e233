"""Calibration of inVAErt and NPE on simulated cases of the EHR prior, as workflow steps.

Held-out cases: ``n_cases`` rows of the EHR study's simulated validation split (the same
rows, and the same standard-normal noise draw scaled by delta, at every noise level), with
noisy observations y' = y + eta(delta) in physical units. Each method gives ``n_samples``
parameter sets per case: inVAErt decodes y' with latent draws w ~ N(0, I) (its spread is a
sample of the non-identifiable manifold of y', not a Bayesian posterior), NPE samples its
posterior q(theta | y'). The diagnostics are those of :mod:`cvsim6.inference.calibration`.

Non-identifiable parameters are marked by the structural study's local check
(:mod:`cvsim6.model.identifiability`): simulator Jacobians at the cases' true parameters, a
parameter's mean null-space share above ``nonidentifiable_share``.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from cvsim6.inference import calibration
from cvsim6.model import identifiability
from cvsim6.inference import inversion
from cvsim6.nets import DEFAULT_CORRECTOR_STEPS, load_model
from cvsim6.inference.npe import load_npe
from cvsim6.data.priors import prior_bounds
from cvsim6.registry import PARAMETER_NAMES
from cvsim6.table_files import to_markdown
from cvsim6.studies.cases import calibration_cases

log = logging.getLogger(__name__)

#: The two inverse methods compared, in table and legend order.
METHODS = ("inVAErt", "NPE")


def calibration_samples(validation: str, encoder_decoder: str, npe: str, samples: str, noise_level: float,
                        n_cases: int, n_samples: int, seed: int,
                        corrector_steps: int = DEFAULT_CORRECTOR_STEPS, threads: int = 1) -> None:
    """Workflow step: the cases of one noise level and ``n_samples`` parameter sets per case
    from each method, in one ``.npz`` (``theta``, ``y_obs``, ``inVAErt``, ``NPE`` (n, N, 23),
    ``noise_level``, ``seconds_<method>``: wall time of the sampling)."""
    torch.set_num_threads(int(threads))
    theta, _, y_obs = calibration_cases(validation, n_cases, noise_level, seed)
    t0 = time.perf_counter()
    inv = inversion.decode_latent(load_model(encoder_decoder), y_obs, int(n_samples), seed=seed,
                                  corrector_steps=corrector_steps)
    t1 = time.perf_counter()
    npe_samples = load_npe(npe).sample(y_obs, int(n_samples), seed=seed)
    t2 = time.perf_counter()
    Path(samples).parent.mkdir(parents=True, exist_ok=True)
    with open(samples, "wb") as fh:
        np.savez_compressed(fh, theta=theta, y_obs=y_obs, inVAErt=inv, NPE=npe_samples,
                            noise_level=float(noise_level), seconds_inVAErt=t1 - t0, seconds_NPE=t2 - t1)
    log.info("delta=%g: %d cases x %d samples; inVAErt %.1f s, NPE %.1f s", noise_level, len(theta),
             n_samples, t1 - t0, t2 - t1)


def nonidentifiable_parameters(theta: np.ndarray, prior: dict, simulator: dict, n_points: int,
                               rel_step: float, rank_rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean null-space share per parameter (23,) over the Jacobians at the first ``n_points``
    rows of ``theta``, and the local ranks found there."""
    lo, hi = prior_bounds(prior)
    f = identifiability.simulator_outputs(simulator["steps_per_cycle"])
    J = identifiability.finite_difference_jacobian(f, theta[:int(n_points)], hi - lo, rel_step=rel_step)
    ok = np.isfinite(J).all(axis=(1, 2))
    if not ok.any():
        raise ValueError("no finite simulator Jacobian at the calibration cases")
    _, ranks, shares = identifiability.local_identifiability(identifiability.scaled_jacobian(J[ok], hi - lo),
                                                            rank_rtol)
    return shares.mean(axis=0), ranks


def _losses_seconds(paths: list[str]) -> dict[float, float]:
    """Training seconds per noise level from loss CSVs named ``..._delta<d>_losses.csv``."""
    out: dict[float, float] = {}
    for p in paths:
        d = float(Path(p).name.split("_delta")[1].split("_")[0])
        out[d] = out.get(d, 0.0) + float(pd.read_csv(p)["seconds"].sum())
    return out


def calibration_summary(samples: list[str], npe_models: list[str], csv: str, md: str, figure_data: str,
                        prior: dict, simulator: dict, figure_noise_level: float, identifiability_points: int,
                        rel_step: float, rank_rtol: float, nonidentifiable_share: float, seed: int,
                        invaert_losses: list[str] | tuple = ()) -> None:
    """Workflow step: the calibration table (CSV, one row per method, delta and parameter), its
    Markdown summary, and the data of the three calibration figures (``figure_data``, NPZ, see
    :func:`write_figure_data`: coverage curves for every delta; ranks and recovery at
    ``figure_noise_level``), drawn by :mod:`cvsim6.reporting.calibration_figures`."""
    lo, hi = prior_bounds(prior)
    runs = [dict(np.load(p)) for p in samples]
    runs.sort(key=lambda r: float(r["noise_level"]))
    share, ranks = nonidentifiable_parameters(runs[0]["theta"], prior, simulator, identifiability_points,
                                              rel_step, rank_rtol)
    nonid = share > float(nonidentifiable_share)
    log.info("local Jacobian ranks at %d cases: %s; non-identifiable: %s", len(ranks),
             dict(zip(*np.unique(ranks, return_counts=True))), [n for n, b in zip(PARAMETER_NAMES, nonid) if b])
    table, curves = diagnostics_table(runs, lo, hi, share, nonid, seed)
    Path(csv).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(csv, index=False)
    summary = _method_summary(table, runs, npe_models, invaert_losses)
    fig_d = float(figure_noise_level)
    detail = _parameter_detail(table, share, nonid, fig_d)
    n_cases, n_samples = int(table["n_cases"].iloc[0]), int(table["n_samples"].iloc[0])
    text = to_markdown(summary, f"Calibration on {n_cases} simulated validation cases of the EHR prior, "
                                f"{n_samples} samples per case and method. SBC: KS test of rank uniformity; "
                                "coverage error: mean |empirical - nominal| of central intervals at levels "
                                "0.05..0.95; TARP ATC: 0 calibrated, < 0 over-confident, > 0 under-confident; "
                                "contraction 1 - Var_post/Var_prior; NRMSE of the posterior mean in prior "
                                "standard deviations; non-identifiable: mean Jacobian null-space share > "
                                f"{nonidentifiable_share:g}. Training (s): NPE wall time; inVAErt: its "
                                "encoder/decoder epochs (not the emulator it trains through, shared by all noise "
                                "levels; empty when the networks were not trained here)")
    text += "\n" + to_markdown(detail, f"Per parameter at delta = {fig_d:g}")
    Path(md).write_text(text, encoding="utf-8")
    fig_run = next((r for r in runs if float(r["noise_level"]) == fig_d), runs[0])
    write_figure_data(figure_data, curves, fig_run, nonid, lo, hi)


def diagnostics_table(runs: list[dict], lo: np.ndarray, hi: np.ndarray, share: np.ndarray, nonid: np.ndarray,
                      seed: int) -> tuple[pd.DataFrame, dict]:
    """One row per method, noise level and parameter (diagnostics of
    :mod:`cvsim6.inference.calibration`, unitless), and per ``(method, delta)`` the ``diag`` and
    ``tarp`` results the figures draw. ``runs``: the sample files' arrays, by noise level."""
    rows, curves = [], {}
    for r in runs:
        d = float(r["noise_level"])
        for m in METHODS:
            diag = calibration.diagnostics(r["theta"], r[m], lo, hi)
            tarp = calibration.tarp(r["theta"], r[m], lo, hi, seed=seed)
            curves[(m, d)] = dict(diag=diag, tarp=tarp)
            for j, name in enumerate(PARAMETER_NAMES):
                rows.append({"method": m, "noise_level": d, "parameter": name, "non_identifiable": bool(nonid[j]),
                             "null_space_share": share[j], "sbc_pvalue": diag["sbc_pvalue"][j],
                             "coverage_error": diag["coverage_error"][j], "contraction": diag["contraction"][j],
                             "nrmse": diag["nrmse"][j], "tarp_atc": tarp["atc"], "tarp_ks_pvalue": tarp["ks_pvalue"],
                             "n_cases": len(r["theta"]), "n_samples": r[m].shape[1]})
    return pd.DataFrame(rows), curves


def _method_summary(table: pd.DataFrame, runs: list[dict], npe_models: list[str],
                    invaert_losses: list[str] | tuple) -> pd.DataFrame:
    """One row per method and noise level: counts and means of the diagnostics, and the
    sampling and training wall times (s)."""
    npe_info = {float(info.get("noise_level", np.nan)): info for info in (load_npe(p).info for p in npe_models)}
    inv_seconds = _losses_seconds(list(invaert_losses))
    summary = []
    for (m, d), grp in table.groupby(["method", "noise_level"], sort=False):
        run = next(r for r in runs if float(r["noise_level"]) == d)
        summary.append({
            "Method": m, "delta": d,
            "SBC p < 0.01 (of 23)": int((grp["sbc_pvalue"] < 0.01).sum()),
            "Coverage error (mean)": grp["coverage_error"].mean(),
            "TARP ATC": grp["tarp_atc"].iloc[0],
            "Contraction (identifiable)": grp.loc[~grp["non_identifiable"], "contraction"].mean(),
            "Contraction (non-identifiable)": grp.loc[grp["non_identifiable"], "contraction"].mean(),
            "NRMSE (identifiable)": grp.loc[~grp["non_identifiable"], "nrmse"].mean(),
            "NRMSE (non-identifiable)": grp.loc[grp["non_identifiable"], "nrmse"].mean(),
            "Sampling (s)": float(run[f"seconds_{m}"]),
            "Training (s)": (npe_info.get(d, {}).get("train_seconds", np.nan) if m == "NPE"
                             else inv_seconds.get(d, np.nan)),
        })
    return pd.DataFrame(summary)


def _parameter_detail(table: pd.DataFrame, share: np.ndarray, nonid: np.ndarray, delta: float) -> pd.DataFrame:
    """Per parameter at noise level ``delta``: its identifiability and each method's diagnostics."""
    per_param = table[table["noise_level"] == delta].pivot(index="parameter", columns="method")
    detail = pd.DataFrame({"Parameter": list(PARAMETER_NAMES),
                           "Non-identifiable": ["yes" if b else "" for b in nonid], "Null-space share": share})
    for col, label in (("sbc_pvalue", "SBC p"), ("coverage_error", "Coverage error"),
                       ("contraction", "Contraction"), ("nrmse", "NRMSE")):
        for m in METHODS:
            detail[f"{label} ({m})"] = per_param.loc[list(PARAMETER_NAMES), (col, m)].to_numpy()
    return detail


def write_figure_data(path: str, curves: dict, run: dict, nonid: np.ndarray, lo: np.ndarray,
                      hi: np.ndarray) -> None:
    """The arrays the calibration figures draw, in one ``.npz`` (M methods, D noise levels,
    L coverage levels, n cases, 23 parameters; all unitless):

    * ``methods`` (M,), ``parameters`` (23,), ``non_identifiable`` (23,) bool;
    * ``noise_levels`` (D,), ``coverage_levels`` (L,), ``coverage`` (M, D, L, 23): empirical
      coverage of the central intervals; ``tarp_alpha``, ``tarp_ecp`` (M, D, A): TARP curves;
    * at ``figure_noise_level`` (the delta of ``run``): ``ranks`` (M, n, 23), SBC ranks among
      ``n_samples`` samples; ``true_fraction`` (n, 23) and ``posterior_mean_fraction`` (M, n, 23),
      the true parameters and the sample means as fractions of the prior width (``lo``, ``hi``).
    """
    deltas = sorted({d for _, d in curves})
    delta = float(run["noise_level"])
    means = [np.stack([(run[m][:, :, j].mean(axis=1) - lo[j]) / (hi[j] - lo[j]) for j in range(len(lo))], axis=1)
             for m in METHODS]
    arrays = dict(
        methods=np.array(METHODS), parameters=np.array(PARAMETER_NAMES), non_identifiable=np.asarray(nonid, bool),
        noise_levels=np.array(deltas, float), coverage_levels=np.asarray(calibration.COVERAGE_LEVELS, float),
        coverage=np.array([[curves[(m, d)]["diag"]["coverage"] for d in deltas] for m in METHODS]),
        tarp_alpha=np.array([[curves[(m, d)]["tarp"]["alpha"] for d in deltas] for m in METHODS]),
        tarp_ecp=np.array([[curves[(m, d)]["tarp"]["ecp"] for d in deltas] for m in METHODS]),
        figure_noise_level=delta, n_samples=int(run["inVAErt"].shape[1]),
        ranks=np.array([curves[(m, delta)]["diag"]["ranks"] for m in METHODS]),
        true_fraction=(run["theta"] - lo) / (hi - lo), posterior_mean_fraction=np.array(means),
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
