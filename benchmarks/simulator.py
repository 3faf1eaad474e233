"""Benchmark: batch vs reference simulator on the same N sets from the EHR prior.

Runs N sets through each path (one process, one thread) and reports the sets per CPU-second
of each, the batch path's speed as a ratio to the reference path's (both measured in this
run), and the worst relative and absolute error per output of batch against reference. The
batch path is timed after a warm-up call (numba compiles once and caches to disk, so a second
process does not pay it); that first call's time is reported apart. CPU seconds are the
process's (``time.process_time``), wall seconds beside them.

    .venv/bin/python benchmarks/simulator.py --n-reference 6 --n-batch 4000

Writes ``benchmarks/results/simulator.json``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from cvsim6.data import priors
from cvsim6 import registry
from cvsim6.model import solver


def timed(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, its CPU seconds (this process) and its wall seconds."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - c0, time.perf_counter() - w0


def ehr_prior_sets(n: int, seed: int) -> np.ndarray:
    """``n`` parameter sets (rows, registry units) drawn uniformly from the EHR study's prior."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["ehr"])
    return priors.sample_uniform(lo, hi, n, np.random.default_rng(seed))


def main() -> None:
    import results_io

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-reference", type=int, default=6, help="sets through the reference path")
    ap.add_argument("--n-batch", type=int, default=4000, help="sets through the batch path")
    ap.add_argument("--steps-per-cycle", type=int, default=solver.DEFAULT_STEPS_PER_CYCLE)
    ap.add_argument("--seed", type=int, default=0)
    results_io.add_note_argument(ap)
    args = ap.parse_args()
    run = results_io.Run()

    P = ehr_prior_sets(max(args.n_batch, args.n_reference), args.seed)

    _, _, t_first = timed(solver.simulate_batch, P[:1], steps_per_cycle=args.steps_per_cycle)
    (out, st), cpu_b, wall_b = timed(solver.simulate_batch, P[: args.n_batch], steps_per_cycle=args.steps_per_cycle)
    (ref, rst), cpu_r, wall_r = timed(solver.simulate_reference, P[: args.n_reference])

    rate_b, rate_r = args.n_batch / cpu_b, args.n_reference / cpu_r
    speed = pd.DataFrame({
        "path": ["batch", "reference"], "sets": [args.n_batch, args.n_reference],
        "flagged": [int((st != 0).sum()), int((rst != 0).sum())], "cpu_s": [cpu_b, cpu_r], "wall_s": [wall_b, wall_r],
        "sets_per_cpu_s": [rate_b, rate_r], "speed_vs_reference": [rate_b / rate_r, 1.0],
        "wall_speed_vs_reference": [(args.n_batch / wall_b) / (args.n_reference / wall_r), 1.0]})
    ok = (st[: args.n_reference] == 0) & (rst == 0)
    absd = np.abs(out[: args.n_reference] - ref)
    rel = absd / np.abs(ref)
    accuracy = pd.DataFrame({"output": list(registry.OUTPUT_NAMES), "unit": [o.unit for o in registry.OUTPUTS],
                             "max_rel_error": rel[ok].max(axis=0), "max_abs_error": absd[ok].max(axis=0)})
    once = pd.DataFrame({"quantity": ["first batch call (compile or cache load), wall s",
                                      "sets compared (neither path flagged)", "steps per cardiac cycle (batch)"],
                         "value": [t_first, int(ok.sum()), args.steps_per_cycle]})

    print(f"first batch call (compile or cache load): {t_first:.2f} s")
    print(speed.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    print(f"worst error of batch vs reference over {int(ok.sum())} sets:")
    print(accuracy.to_string(index=False, float_format=lambda x: f"{x:.2e}"))
    run.save(
        "simulator", "Simulator: batch path against the reference solver",
        "The same parameter sets from the EHR prior through the batch simulator (the workflow's) and "
        "the reference solver, one thread: sets per CPU-second and the batch path's speed as a ratio to "
        "the reference's in the same run; then the worst error of the batch outputs against the "
        "reference's over the sets neither path flagged.",
        [results_io.table(speed, "speed", "Speed, one thread (ratios against the reference path of the same run).",
                          {"cpu_s": ".3g", "wall_s": ".3g", "sets_per_cpu_s": ".4g", "speed_vs_reference": ",.0f",
                           "wall_speed_vs_reference": ",.0f"}),
         results_io.table(accuracy, "accuracy",
                          "Worst error of the batch path against the reference solver, per output.",
                          {"max_rel_error": ".2e", "max_abs_error": ".2e"}),
         results_io.table(once, "setup", "Setup of the measurement.", {"value": ".3g"})],
        parameters={k: v for k, v in vars(args).items() if k != "note"}, note=args.note)


if __name__ == "__main__":
    main()
