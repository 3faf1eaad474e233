"""Benchmark: accuracy per CPU-second of the batch simulator and the reference solver.

A work-precision measurement: the same parameter sets of the EHR prior through the batch path at
several steps per cardiac cycle and through the reference solver (scipy Radau) at several
tolerances, each output compared with a tightly converged solve (Radau, rtol = atol = 1e-10).
Errors are given relative to the output and in units of its measurement-noise standard deviation
(:func:`cvsim6.registry.noise_std`, the unit the EHR networks' noise levels use). Speeds are sets
per CPU-second, one thread, as ratios to Radau at the paper code's tolerance (rtol 1e-6) in the
same run; then, per reference tolerance, the cheapest batch setting at least as accurate and its
speed at that accuracy.

    .venv/bin/python benchmarks/simulator_accuracy.py --n-sets 12 --n-timing 2000

Writes ``benchmarks/results/simulator_accuracy.json``.
"""
from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

from cvsim6 import registry
from cvsim6.model import solver

#: The tolerance of the paper's own code (rtol; here atol = rtol), the speed baseline.
PAPER_RTOL = 1e-6


def errors(y: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Worst errors of ``y`` (sets, 16) against ``truth``: relative (over every set and output),
    in measurement-noise standard deviations (the same), and the median over sets of each set's
    worst error in noise standard deviations."""
    if len(y) == 0:  # every set flagged by some setting: nothing to compare
        return dict.fromkeys(("max_rel_error", "max_error_noise_sd", "median_set_error_noise_sd"), np.nan)
    absd = np.abs(y - truth)
    in_noise = absd / registry.noise_std()
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(truth != 0, absd / np.abs(truth), np.nan)  # an output of exactly 0 has no relative error
    return {"max_rel_error": float(np.nanmax(rel)), "max_error_noise_sd": float(in_noise.max()),
            "median_set_error_noise_sd": float(np.median(in_noise.max(axis=1)))}


def equal_accuracy(points: pd.DataFrame, metric: str = "max_error_noise_sd") -> pd.DataFrame:
    """Per reference setting (rows with ``path == "reference"`` and an error), the batch setting
    of most sets per CPU-second whose ``metric`` is at or below the reference's, and the batch
    path's speed as a ratio to that reference setting's (NaN where no batch setting is as
    accurate)."""
    batch = points[points["path"] == "batch"]
    rows = []
    for _, ref in points[(points["path"] == "reference") & points[metric].notna()].iterrows():
        ok = batch[batch[metric] <= ref[metric]]
        best = ok.loc[ok["sets_per_cpu_s"].idxmax()] if len(ok) else None
        rows.append({"reference": ref["setting"], metric: ref[metric],
                     "batch": best["setting"] if best is not None else "none",
                     f"batch {metric}": best[metric] if best is not None else np.nan,
                     "speed_at_equal_accuracy": (best["sets_per_cpu_s"] / ref["sets_per_cpu_s"]
                                                 if best is not None else np.nan)})
    out = pd.DataFrame(rows, columns=["reference", metric, "batch", f"batch {metric}", "speed_at_equal_accuracy"])
    out["speed_at_equal_accuracy"] = _three_digits(out["speed_at_equal_accuracy"])
    return out


def _three_digits(x: pd.Series) -> pd.Series:
    """``x`` to three significant digits (speed ratios: their last digits are timing noise)."""
    return x.map(lambda v: float(f"{v:.3g}"))


def measure(P: np.ndarray, n_sets: int, steps: list[int], rtols: list[float], truth_rtol: float) -> pd.DataFrame:
    """One row per setting: errors on the first ``n_sets`` rows of ``P`` against Radau at
    ``truth_rtol``, CPU seconds per set (batch: over all rows of ``P``; reference: over the
    ``n_sets``), sets per CPU-second and the speed ratio to Radau at :data:`PAPER_RTOL`."""
    from simulator import timed
    (truth, tst), cpu_truth, _ = timed(solver.simulate_reference, P[:n_sets], rtol=truth_rtol, atol=truth_rtol)
    solver.simulate_batch(P[:1], steps_per_cycle=steps[0])  # compile or load the kernel, untimed
    runs = [("reference", f"rtol {truth_rtol:g} (truth)", (truth, tst), cpu_truth, n_sets)]
    for s in steps:
        (out, st), cpu, _ = timed(solver.simulate_batch, P, steps_per_cycle=s)
        runs.append(("batch", f"{s} steps/cycle", (out[:n_sets], st[:n_sets]), cpu, len(P)))
    for r in rtols:
        (out, st), cpu, _ = timed(solver.simulate_reference, P[:n_sets], rtol=r, atol=r)
        runs.append(("reference", f"rtol {r:g}", (out, st), cpu, n_sets))
    ok = (tst == 0) & np.logical_and.reduce([st == 0 for _, _, (_, st), _, _ in runs])
    rows = []
    for path, setting, (out, st), cpu, n in runs:
        err = errors(out[ok], truth[ok]) if "truth" not in setting else errors(truth[:0], truth[:0])
        rows.append({"path": path, "setting": setting, "sets_timed": n, "flagged": int((st != 0).sum()),
                     "cpu_s_per_set": cpu / n, "sets_per_cpu_s": n / cpu, **err})
    df = pd.DataFrame(rows)
    base = df.loc[df["setting"] == f"rtol {PAPER_RTOL:g}", "sets_per_cpu_s"]
    df["speed_vs_paper_rtol"] = _three_digits(df["sets_per_cpu_s"] / (float(base.iloc[0]) if len(base) else np.nan))
    df.attrs["compared"] = int(ok.sum())
    return df


def main() -> None:
    import results_io
    from simulator import ehr_prior_sets

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-sets", type=int, default=12, help="sets compared with the converged solve")
    ap.add_argument("--n-timing", type=int, default=2000, help="sets timed through each batch setting")
    ap.add_argument("--steps", type=int, nargs="+", default=[100, 150, 200, 300, 400, 600, 900, 1200, 2400])
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-4, PAPER_RTOL, 1e-8])
    ap.add_argument("--truth-rtol", type=float, default=1e-10)
    ap.add_argument("--seed", type=int, default=0)
    results_io.add_note_argument(ap)
    args = ap.parse_args()
    run = results_io.Run()

    P = ehr_prior_sets(max(args.n_timing, args.n_sets), args.seed)
    points = measure(P, args.n_sets, args.steps, args.rtols, args.truth_rtol)
    equal = equal_accuracy(points)
    fmt = {"cpu_s_per_set": ".3g", "sets_per_cpu_s": ".4g", "max_rel_error": ".2e", "max_error_noise_sd": ".2e",
           "median_set_error_noise_sd": ".2e", "speed_vs_paper_rtol": ",.6g"}
    print(points.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    print(equal.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    run.save(
        "simulator_accuracy", "Simulator: accuracy per CPU-second (work-precision)",
        f"The first {args.n_sets} parameter sets of the EHR prior (seed {args.seed}) through the batch path at "
        f"each number of steps per cardiac cycle and through scipy Radau at each tolerance (atol = rtol), one "
        f"thread, compared with Radau at rtol {args.truth_rtol:g} over the {points.attrs['compared']} sets no "
        f"setting flagged: the worst error relative to the output and in units of the output's measurement-noise "
        f"standard deviation (the EHR noise levels' unit), the median over sets of each set's worst error in "
        f"those units, and sets per CPU-second (batch timed on {len(P)} sets, Radau on the {args.n_sets}) as a "
        f"ratio to Radau at the paper code's tolerance, "
        f"rtol {PAPER_RTOL:g}. Then, per Radau tolerance, the fastest batch setting at least as accurate "
        f"(worst error in noise standard deviations) and its speed at that accuracy.",
        [results_io.table(points, "work_precision", "Error and speed per setting (speed ratios against Radau at "
                                                    f"rtol {PAPER_RTOL:g}, same run).", fmt),
         results_io.table(equal, "equal_accuracy", "Speed of the batch path at the accuracy of each Radau tolerance.",
                          {"max_error_noise_sd": ".2e", "batch max_error_noise_sd": ".2e",
                           "speed_at_equal_accuracy": ",.6g"})],
        parameters={k: v for k, v in vars(args).items() if k != "note"}, note=args.note)


if __name__ == "__main__":
    main()
