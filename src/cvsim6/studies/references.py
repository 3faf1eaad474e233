"""Reference posteriors beside the amortized methods, as workflow steps.

Cases at one noise level delta (paper: 0.5): the first ``n_simulated`` simulated cases of the
calibration stage (:func:`cvsim6.studies.cases.calibration_cases`: the same validation
rows and noisy observations y' as there, all 16 outputs observed) and ``n_patients`` EHR
patients drawn (seeded) from the selected ones, their observed outputs only. Each case gets
an MCMC reference posterior (:mod:`cvsim6.inference.reference_posterior`) under the EHR prior
box and a Gaussian likelihood with standard deviation delta s_k, and is compared with
inVAErt's decoded sets and NPE's samples for the same case: those of the calibration stage
(simulated cases) and of the EHR study (patients; both methods invert Algorithm 1's completed
outputs, the reference conditions on the observed ones alone). Units: registry units; prior-box
units are fractions of the prior width.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.data.priors import prior_bounds
from cvsim6.inference import reference_posterior as rp
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES, noise_std
from cvsim6.table_files import to_markdown, write_table
from cvsim6.seeding import derived_seed
from cvsim6.studies.cases import calibration_cases

log = logging.getLogger(__name__)

#: The amortized methods compared with the reference, in table order.
METHODS = ("inVAErt", "NPE")
#: Case kinds: simulated calibration cases and EHR patients.
KINDS = {"sim": "simulated", "ehr": "patient"}
#: Random streams (of the master seed): the patient draw; per case, MCMC (+ case position) and C2ST.
PATIENT_STREAM, MCMC_STREAM, C2ST_STREAM = 4201, 4300, 4202


def case_names(n_simulated: int, n_patients: int) -> list[str]:
    """Case names in order: ``sim0 .. sim{n-1}``, then ``ehr0 .. ehr{m-1}``."""
    return [f"sim{i}" for i in range(int(n_simulated))] + [f"ehr{i}" for i in range(int(n_patients))]


def reference_cases(validation: str, patients: str, cases: str, n_simulated: int, n_patients: int,
                    calibration_n_cases: int, noise_level: float, seed: int) -> None:
    """Workflow step: the cases (CSV, one row each): ``case``, ``kind``, ``source`` (calibration
    case index, or patient id), the 16 observations ``y_<output>`` (NaN: not observed) and, for
    simulated cases, the true parameters ``theta_<parameter>``."""
    if int(n_simulated) > int(calibration_n_cases):
        raise ValueError(f"references n_simulated = {n_simulated} exceeds the calibration stage's "
                         f"n_cases = {calibration_n_cases}: its cases are the references' simulated ones")
    theta, _, y_obs = calibration_cases(validation, calibration_n_cases, noise_level, seed)
    pts = pd.read_csv(patients, index_col="patient")
    if int(n_patients) > len(pts):
        raise ValueError(f"references n_patients = {n_patients} exceeds the {len(pts)} selected EHR patients")
    rng = np.random.default_rng(derived_seed(seed, PATIENT_STREAM))
    pick = np.sort(rng.choice(len(pts), size=int(n_patients), replace=False))
    rows = []
    for i in range(int(n_simulated)):
        rows.append({"case": f"sim{i}", "kind": KINDS["sim"], "source": str(i),
                     **{f"y_{n}": y_obs[i, j] for j, n in enumerate(OUTPUT_NAMES)},
                     **{f"theta_{n}": theta[i, j] for j, n in enumerate(PARAMETER_NAMES)}})
    for i, k in enumerate(pick):
        rows.append({"case": f"ehr{i}", "kind": KINDS["ehr"], "source": str(pts.index[k]),
                     **{f"y_{n}": float(pts.iloc[k][n]) for n in OUTPUT_NAMES},
                     **{f"theta_{n}": np.nan for n in PARAMETER_NAMES}})
    Path(cases).parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(cases, index=False)


def _case_row(cases: str, case: str) -> tuple[pd.Series, int]:
    df = pd.read_csv(cases, dtype={"source": str})
    hit = np.flatnonzero(df["case"].to_numpy() == case)
    if len(hit) != 1:
        raise ValueError(f"case {case!r} is not in {cases} (cases: {', '.join(df['case'])})")
    return df.iloc[int(hit[0])], int(hit[0])


def reference_mcmc(cases: str, chain: str, case: str, prior: dict, simulator: dict, noise_level: float,
                   walkers: int, start_prior_draws: int, start_iterations: int, min_steps: int, max_steps: int,
                   check_every: int, rhat_max: float, ess_min: float, keep: int, seed: int) -> None:
    """Workflow step: the reference posterior of one case (``.npz``: ``samples`` (<= keep, 23)
    thinned from the kept half of the chain, registry units; the diagnostics of
    :func:`cvsim6.inference.reference_posterior.run_ensemble`; ``cpu_seconds`` and
    ``wall_seconds`` of the whole step)."""
    cpu0, wall0 = time.process_time(), time.perf_counter()
    row, position = _case_row(cases, case)
    lo, hi = prior_bounds(prior)
    y = row[[f"y_{n}" for n in OUTPUT_NAMES]].to_numpy(float)
    post = rp.BoxPosterior(rp.simulator_function(simulator), y, float(noise_level) * noise_std(), lo, hi)
    case_seed = derived_seed(seed, MCMC_STREAM + position)
    start = rp.start_walkers(post, int(walkers), np.random.default_rng(case_seed), int(start_prior_draws),
                             int(start_iterations))
    log.info("case %s (%s %s): %d observed outputs; start after %d simulations", case, row["kind"], row["source"],
             int(post.observed.sum()), post.evaluations)
    res = rp.run_ensemble(post, start, case_seed, min_steps, max_steps, check_every, rhat_max, ess_min,
                          progress=True)
    chain_u = res.pop("chain")
    samples = post.to_physical(rp.thin(chain_u, int(keep)))
    Path(chain).parent.mkdir(parents=True, exist_ok=True)
    with open(chain, "wb") as fh:
        np.savez_compressed(fh, samples=samples, case=case, kind=row["kind"], source=str(row["source"]),
                            walkers=int(walkers), n_samples=int(chain_u.shape[0] * chain_u.shape[1]),
                            observed=post.observed, start_evaluations=post.evaluations - res["evaluations"],
                            cpu_seconds=time.process_time() - cpu0, wall_seconds=time.perf_counter() - wall0,
                            **{k: np.asarray(v) for k, v in res.items()})
    log.info("case %s: %d steps, R-hat max %.3f, converged %s, %.0f s CPU", case, res["steps"], res["rhat"].max(),
             res["converged"], time.process_time() - cpu0)


def _diagnostic_row(z: dict, rhat_max: float, ess_min: float) -> dict:
    ess = np.minimum(z["ess_bulk"], z["ess_tail"])
    worst = [PARAMETER_NAMES[j] for j in np.flatnonzero((z["rhat"] > rhat_max) | (ess < ess_min))]
    return {"case": str(z["case"]), "kind": str(z["kind"]), "rhat_max": float(z["rhat"].max()),
            "ess_min": float(ess.min()), "n_samples": int(z["n_samples"]), "cpu_seconds": float(z["cpu_seconds"]),
            "wall_seconds": float(z["wall_seconds"]), "steps": int(z["steps"]), "walkers": int(z["walkers"]),
            "acceptance": float(z["acceptance"]), "simulations": int(z["evaluations"] + z["start_evaluations"]),
            "observed_outputs": int(np.asarray(z["observed"]).sum()), "converged": bool(z["converged"]),
            "not converged": ", ".join(worst)}


def reference_diagnostics(chains: list[str], csv: str, md: str, rhat_max: float, ess_min: float) -> None:
    """Workflow step: one row per case: R-hat (max over parameters), ESS (min over parameters
    of bulk and tail), draws, CPU and wall seconds, steps, acceptance, simulations, and the
    parameters short of R-hat <= ``rhat_max`` or ESS >= ``ess_min``."""
    rows = [_diagnostic_row(dict(np.load(p)), rhat_max, ess_min) for p in chains]
    table = pd.DataFrame(rows)
    n_ok = int(table["converged"].sum())
    write_table(table, csv, md, caption=f"MCMC reference posteriors (emcee, DE moves): {n_ok} of {len(table)} "
                                        f"cases reach R-hat <= {rhat_max:g} and ESS >= {ess_min:g} for every "
                                        f"parameter; {table['cpu_seconds'].sum():.0f} CPU seconds in all")


def _method_samples(row: pd.Series, calibration: dict, invaert: pd.DataFrame, npe: pd.DataFrame) -> dict:
    """inVAErt's and NPE's parameter sets (n, 23) for one case, registry units."""
    if row["kind"] == KINDS["sim"]:
        i = int(row["source"])
        y_case = row[[f"y_{n}" for n in OUTPUT_NAMES]].to_numpy(float)
        if not np.allclose(calibration["y_obs"][i], y_case, rtol=1e-12, atol=0):
            raise ValueError(f"case {row['case']}: the calibration samples were drawn for other observations "
                             "(rerun the calibration stage with the same seed and n_cases)")
        return {m: np.asarray(calibration[m][i], float) for m in METHODS}
    out = {}
    for m, df in zip(METHODS, (invaert, npe)):
        part = df[(df["id"].astype(str) == str(row["source"])) & (df["status"] == "ok")]
        out[m] = part[list(PARAMETER_NAMES)].to_numpy(float)
    return out


def reference_comparison(cases: str, chains: list[str], calibration_samples: str, invaert_predictions: str,
                         npe_predictions: str, csv: str, md: str, parameters_csv: str, figure_data: str,
                         prior: dict, figure_cases: list, c2st_folds: int, seed: int) -> None:
    """Workflow step: per case and method, C2ST against the reference, and per parameter the
    difference of posterior means (prior-box units) and the ratio of posterior standard
    deviations, summarised (``csv``/``md``) and in full (``parameters_csv``); the unit-box
    samples of ``figure_cases`` for the marginals figure (``figure_data``, NPZ)."""
    lo, hi = prior_bounds(prior)
    table = pd.read_csv(cases, dtype={"source": str}).set_index("case", drop=False)
    cal = dict(np.load(calibration_samples))
    inv, npe = pd.read_parquet(invaert_predictions), pd.read_parquet(npe_predictions)
    refs = {str(z["case"]): z for z in (dict(np.load(p)) for p in chains)}
    rows, per_param, fig = [], [], {}
    for case, z in refs.items():
        row = table.loc[case]
        got = _method_samples(row, cal, inv, npe)
        for k, m in enumerate(METHODS):
            diff, ratio = rp.compare_moments(z["samples"], got[m], lo, hi)
            acc = rp.c2st_accuracy(z["samples"], got[m], derived_seed(seed, C2ST_STREAM), int(c2st_folds))
            finite = np.isfinite(diff)
            rows.append({"case": case, "method": m, "c2st": acc, "kind": row["kind"],
                         "n_method": int(np.isfinite(got[m]).all(axis=1).sum()), "n_reference": len(z["samples"]),
                         "converged": bool(z["converged"]),
                         "mean_diff_mean": float(np.abs(diff).mean()) if finite.any() else np.nan,
                         "mean_diff_max": float(np.abs(diff).max()) if finite.any() else np.nan,
                         "mean_diff_max_parameter": PARAMETER_NAMES[int(np.nanargmax(np.abs(diff)))]
                         if finite.any() else "",
                         "width_ratio_median": float(np.nanmedian(ratio)) if finite.any() else np.nan,
                         "width_ratio_min": float(np.nanmin(ratio)) if finite.any() else np.nan,
                         "width_ratio_max": float(np.nanmax(ratio)) if finite.any() else np.nan})
            per_param += [{"case": case, "kind": row["kind"], "method": m, "parameter": n, "mean_diff": diff[j],
                           "width_ratio": ratio[j]} for j, n in enumerate(PARAMETER_NAMES)]
        if case in figure_cases:
            fig[f"reference__{case}"] = (z["samples"] - lo) / (hi - lo)
            for m in METHODS:
                fig[f"{m}__{case}"] = (got[m] - lo) / (hi - lo)
            fig[f"truth__{case}"] = (row[[f"theta_{n}" for n in PARAMETER_NAMES]].to_numpy(float) - lo) / (hi - lo)
    out = pd.DataFrame(rows)
    summary = (out.groupby(["kind", "method"], sort=False)[["c2st", "mean_diff_mean", "width_ratio_median"]]
               .median().reset_index())
    write_table(out, csv, md, caption="inVAErt and NPE against the MCMC reference posterior per case: C2ST "
                                      "accuracy (0.5: indistinguishable, 1: disjoint), |difference of the posterior "
                                      "means| in prior-box units (mean and max over parameters), posterior "
                                      "standard deviation / the reference's (median, min, max over parameters)")
    with open(md, "a", encoding="utf-8") as fh:
        fh.write("\n" + to_markdown(summary, "Medians over the cases of each kind"))
    pd.DataFrame(per_param).to_csv(parameters_csv, index=False)
    Path(figure_data).parent.mkdir(parents=True, exist_ok=True)
    with open(figure_data, "wb") as fh:
        np.savez_compressed(fh, parameters=np.array(PARAMETER_NAMES), **fig)
