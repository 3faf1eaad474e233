"""Benchmark: batch vs reference simulator on the same N sets from the EHR prior.

Prints sets/s/core of each path (one process, one thread), their ratio, and the
worst relative error per output of batch against reference. The batch path is
timed after a warm-up call (numba compiles once and caches to disk, so a second
process does not pay it); the compile/cache-load time is printed separately.

    .venv/bin/python benchmarks/simulator.py --n-reference 6 --n-batch 4000
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cvsim6.data import priors
from cvsim6 import registry
from cvsim6.model import solver


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-reference", type=int, default=6, help="sets through the reference path")
    ap.add_argument("--n-batch", type=int, default=4000, help="sets through the batch path")
    ap.add_argument("--steps-per-cycle", type=int, default=solver.DEFAULT_STEPS_PER_CYCLE)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["ehr"])
    P = priors.sample_uniform(lo, hi, max(args.n_batch, args.n_reference), np.random.default_rng(args.seed))

    t0 = time.perf_counter()
    solver.simulate_batch(P[:1], steps_per_cycle=args.steps_per_cycle)
    t_first = time.perf_counter() - t0

    t0 = time.perf_counter()
    out, st = solver.simulate_batch(P[: args.n_batch], steps_per_cycle=args.steps_per_cycle)
    t_batch = time.perf_counter() - t0

    t0 = time.perf_counter()
    ref, rst = solver.simulate_reference(P[: args.n_reference])
    t_ref = time.perf_counter() - t0

    rate_b = args.n_batch / t_batch
    rate_r = args.n_reference / t_ref
    print(f"first batch call (compile or cache load): {t_first:.2f} s")
    print(f"batch     : {rate_b:10.1f} sets/s/core  ({args.n_batch} sets, {t_batch:.2f} s, "
          f"{args.steps_per_cycle} steps/cycle, {int((st != 0).sum())} flagged)")
    print(f"reference : {rate_r:10.4f} sets/s/core  ({args.n_reference} sets, {t_ref:.1f} s)")
    print(f"speed-up  : {rate_b / rate_r:10.0f}x")
    print(f"54,000 sets on 2 cores (batch): {54000 / (2 * rate_b):.0f} s")
    ok = (st[: args.n_reference] == 0) & (rst == 0)
    rel = np.abs(out[: args.n_reference] - ref) / np.abs(ref)
    absd = np.abs(out[: args.n_reference] - ref)
    print(f"worst error of batch vs reference over {int(ok.sum())} sets:")
    for j, name in enumerate(registry.OUTPUT_NAMES):
        print(f"  {name:9s} rel {rel[ok, j].max():.2e}   abs {absd[ok, j].max():.2e} {registry.OUTPUTS[j].unit}")


if __name__ == "__main__":
    main()
