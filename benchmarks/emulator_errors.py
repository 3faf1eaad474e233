"""Benchmark: the emulator's relative l2 error on the validation sets, per architecture variant.

Trains the study's emulator (config/config.yaml's schedule with ``--epochs`` epochs, one
initialization, one thread per process, ``--jobs`` side by side) once per variant on the
workflow's data (``results/data/<study>/``, so run the data stage first), and prints per variant
the worst, 99th-percentile and median relative l2 error ``||f(v) - y|| / ||y||`` over the
validation sets (the paper's EHR-emulator metric), the held-out MSE, the CPU seconds, and the
output holding the largest share of the mean squared relative error; for the structural study
also the scorecard's appendix-C rows (geometric mean over the outputs of ours / paper for the
mean and the max absolute error). Variants: ``paper``
(``linear_skip`` and ``log_inputs`` off), ``log``, ``skip``, ``skip+log``, or any
``--variant NAME='{yaml}'`` merged onto the config's emulator.

    .venv/bin/python benchmarks/emulator_errors.py --study ehr --epochs 2000 --jobs 2

Writes ``benchmarks/results/emulator_errors_<study>.json``.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {"paper": {"linear_skip": False, "log_inputs": False}, "log": {"linear_skip": False, "log_inputs": True},
            "skip": {"linear_skip": True, "log_inputs": False}, "skip+log": {"linear_skip": True, "log_inputs": True}}


def error_summary(y: np.ndarray, y_pred: np.ndarray, names: list[str]) -> dict:
    """Worst / 99th-percentile / median relative l2 error (%) of the rows, and the output with the
    largest share of the mean squared relative error ``mean_i (e_ij / |y_i|)^2`` with that share."""
    from cvsim6.studies.evaluation import relative_l2_errors

    y, y_pred = np.asarray(y, float), np.asarray(y_pred, float)
    rel = relative_l2_errors(y, y_pred)
    norm = np.linalg.norm(y, axis=1)
    share = (((y_pred - y) / norm[:, None]) ** 2).mean(axis=0)
    share = share / share.sum()
    k = int(np.argmax(share))
    return {"worst_%": 100 * rel.max(), "p99_%": 100 * np.quantile(rel, 0.99), "median_%": 100 * np.median(rel),
            "top_output": names[k], "top_share": share[k]}


def appendix_c_ratios(y: np.ndarray, y_pred: np.ndarray) -> dict:
    """The structural study's appendix-C headline: the geometric mean over the 16 outputs of
    ours / paper for the mean and for the max absolute error (the scorecard's two rows)."""
    from cvsim6 import paper_values
    from cvsim6.studies.evaluation import error_statistics
    from cvsim6.reporting.scorecard import geomean_ratio

    stats = error_statistics(y, y_pred)
    paper = paper_values.EMULATOR_VALIDATION_STRUCTURAL
    return {f"appendix_c_{k}_x": geomean_ratio(stats[k], paper[k]) for k in ("mean", "max")}


def _run(job: tuple) -> dict:
    from cvsim6.data import datasets
    from cvsim6.training import train as training
    from cvsim6 import nets as nw
    from cvsim6.registry import OUTPUT_NAMES

    name, study, hyper, seed = job
    data = ROOT / "results" / "data" / study
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        res = training.train_emulator(str(data / "train.parquet"), str(data / "test.parquet"), str(Path(tmp) / "m.pt"),
                                      str(Path(tmp) / "l.csv"), hyper, seed, device="cpu", threads=1,
                                      progress=False, checkpoint_every=10**9)
        cpu = time.process_time() - t0
        emu = nw.load_model(Path(tmp) / "m.pt")
    v, y = datasets.load_split(data / "validation.parquet")
    pred = emu.predict(v)
    row = {"variant": name, **error_summary(y, pred, list(OUTPUT_NAMES))}
    if study == "structural":
        row.update(appendix_c_ratios(y, pred))
    return {**row, "held_out_mse": res["test_loss"], "cpu_s": cpu}


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", default="ehr")
    ap.add_argument("--epochs", type=int, default=None, help="epochs per training (default: the config's)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--configfile", type=Path, default=ROOT / "config" / "config.yaml")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), help=f"of {list(VARIANTS)}")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=YAML")
    import results_io

    results_io.add_note_argument(ap)
    args = ap.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/emulator_errors.py", *argv])
    base = dict(yaml.safe_load(args.configfile.read_text())["training"]["studies"][args.study]["emulator"])
    base.pop("restarts", None)
    base.pop("restart_epochs", None)
    if args.epochs:
        base["epochs"] = args.epochs
    variants = {n: VARIANTS[n] for n in args.variants}
    for v in args.variant:
        n, _, y = v.partition("=")
        variants[n] = yaml.safe_load(y)
    jobs = [(n, args.study, {**base, **over}, args.seed) for n, over in variants.items()]
    with mp.get_context("spawn").Pool(args.jobs) as pool:
        table = pd.DataFrame(pool.map(_run, jobs, chunksize=1))
    print(table.to_markdown(index=False, floatfmt=".3g"))
    formats = {c: ".3g" for c in table.columns if c not in ("variant", "top_output")}
    formats["top_share"] = ".0%"
    run.save(f"emulator_errors_{args.study}", f"Emulator error per architecture variant ({args.study} study)",
             f"The {args.study} study's emulator trained once per variant on the workflow's data (the config's "
             f"schedule, one initialization, one thread each): relative l2 error over the validation sets "
             f"(worst, 99th percentile, median, in %), the held-out MSE, the CPU seconds of the training, and the "
             f"output holding the largest share of the mean squared relative error.",
             [results_io.table(table, "variants", "Per variant.", formats)],
             parameters={"study": args.study, "epochs": base["epochs"], "seed": args.seed, "jobs": args.jobs,
                         "configfile": args.configfile.resolve(),
                         "variants": {n: dict(o) for n, o in variants.items()}}, note=args.note)
    return table


if __name__ == "__main__":
    main()
