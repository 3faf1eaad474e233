"""Benchmark: how many epochs the structural encoder/decoder's continuation needs.

The workflow trains restart candidates of the structural encoder/decoder to epoch
``restart_epochs`` and continues the chosen one to ``epochs`` (:mod:`cvsim6.training.restarts`):
on one core, the longest job of a run. This script continues a finished run's chosen candidate,
from its checkpoint at the choice, under the config's schedule with ``epochs`` = E for each
``--epochs`` E (one thread each, ``--jobs`` side by side), and runs on each model the structural
evaluations behind the scorecard's headlines (table 3, the manifold's reconstruction and its
resampled median, SVD modes, missing data) with the run's config, seed, flow, emulator and y*.
The row ``run`` is the run's own model (E = the config's), evaluated the same way, first: the
script compares it with the run's own headline files and warns when they differ (another config,
code or floating-point path; ``run_row_differs_from_run`` in the result file).

A shortened run is not the same as this continuation for its first ``restart_epochs`` epochs:
the candidate trained them under the cosine of the config's E, so its learning rate at the
switch is that schedule's (a drop to the new schedule's value follows).

    .venv/bin/python benchmarks/continuation_epochs.py --run <run> --epochs 2000 3500 \\
        --work <scratch>/continuation

Output: the table on stdout, and ``benchmarks/results/continuation_epochs.json`` (``--name``).
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

if __name__ == "__main__":  # one BLAS thread per process (not when a test imports this)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import pandas as pd  # noqa: E402
import yaml  # noqa: E402

from cvsim6.reporting import headline_files as layout  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The scorecard's headlines that the structural encoder/decoder moves.
HEADLINES = ("structural_inversion_mean", "structural_inversion_max", "manifold_l2", "manifold_l2_resampled",
             "svd_modes", "missing_l2")
#: The headline files the structural encoder/decoder moves, written by :func:`evaluate` under a
#: model's folder in the workflow's layout of a network source; the others are the run's.
EVALUATED = ("structural_inversion", "manifold", "svd", "missing")
FORMATS = {"continuation_cpu_s": ".0f", "best_test_loss": ".2f", **{f"{h} / paper": ".3f" for h in HEADLINES}}


def continue_candidate(job: tuple) -> tuple[int, float, int]:
    """Continue the chosen candidate (checkpoint ``cand``) to ``epochs``; returns (epochs, CPU
    seconds of this call, epochs trained by it). The continuation's checkpoint is the candidate's
    with the fingerprint of the E-epoch run, so :func:`~cvsim6.training.train.train_encoder_decoder`
    resumes it (a rerun resumes or reads the finished one)."""
    import torch

    from cvsim6.data.datasets import load_split
    from cvsim6.training import loop
    from cvsim6.training import train as training
    from cvsim6.training.hyperparameters import check_hyper

    epochs, out, data, emulator, hyper, seed, cand, restart = job
    h = check_hyper("encoder_decoder", {**hyper, "epochs": epochs})
    train, test = str(data / "train.parquet"), str(data / "test.parquet")
    fp = training.encoder_decoder_fingerprint(h, seed, 0.0, (*load_split(train), *load_split(test)), str(emulator))
    ckpt = out / "models" / "encoder_decoder_delta0.pt.ckpt"
    if (loop.read_checkpoint(ckpt) or {}).get("fingerprint") != fp:
        ck = torch.load(cand, map_location="cpu", weights_only=True)
        loop.save_checkpoint(ckpt, {**ck, "fingerprint": fp, "extra": {"restart": restart}})
    t0 = time.process_time()
    res = training.train_encoder_decoder(train=train, test=test, emulator=str(emulator),
                                         model=str(out / "models" / "encoder_decoder_delta0.pt"),
                                         losses=str(out / "encoder_decoder_delta0_losses.csv"), hyper=h, seed=seed,
                                         device="cpu", threads=1, checkpoint=str(ckpt), progress=False)
    if not res["completed"]:
        raise RuntimeError(f"continuation to {epochs} epochs did not complete: {res}")
    return epochs, time.process_time() - t0, int(res["epochs_this_run"])


def evaluate(encoder_decoder: Path, out: Path, run: Path, cfg: dict, seed: int) -> dict[str, str]:
    """The structural evaluations of the workflow on ``encoder_decoder`` (outputs under ``out``);
    the scorecard's headline files, the others the run's."""
    from cvsim6.studies import structural as s

    res, sc, sim = run / "results", cfg["structural_study"], cfg["simulator"]
    models, cs = res / "models" / "structural", sc["corrector_steps"]
    obs = str(res / "tables" / "structural_observation.csv")
    p = {k: out / Path(layout.PER_NETWORKS[k]).with_suffix("") for k in EVALUATED}
    for f in p.values():
        f.parent.mkdir(parents=True, exist_ok=True)
    ed, samples = str(encoder_decoder), str(out / "structural" / "manifold_samples.parquet")
    s.inversion_table(encoder_decoder=ed, validation=str(res / "data" / "structural" / "validation.parquet"),
                      csv=f"{p['structural_inversion']}.csv", summary=f"{p['structural_inversion']}.json",
                      md=f"{p['structural_inversion']}.md", simulator=sim, seed=seed, corrector_steps=cs)
    s.sample_manifold(encoder_decoder=ed, observation=obs, samples=samples, n_samples=sc["n_manifold"], seed=seed,
                      corrector_steps=cs)
    s.manifold_reconstruction(samples=samples, observation=obs, csv=f"{p['manifold']}.csv",
                              summary=f"{p['manifold']}.json", md=f"{p['manifold']}.md",
                              traces=str(out / "structural" / "manifold_trajectories.csv"),
                              simulator=sim, n_reconstruct=sc["n_reconstruct"], n_traces=sc["n_traces"],
                              emulator=str(models / "emulator.pt"), n_spread=sc["n_spread"],
                              spread_resamples=sc["spread_resamples"], seed=seed)
    s.manifold_svd_modes(samples=samples, csv=f"{p['svd']}.csv", summary=f"{p['svd']}.json")
    s.missing_data(flow=str(models / "flow_delta0.pt"), encoder_decoder=ed, observation=obs, csv=f"{p['missing']}.csv",
                   summary=f"{p['missing']}.json", md=f"{p['missing']}.md",
                   traces=str(out / "structural" / "missing_data_trajectories.csv"), simulator=sim,
                   missing=sc["missing"], n_flow_samples=sc["missing_flow_samples"], top_k=sc["missing_top"],
                   n_latent=sc["missing_latent"], seed=seed, corrector_steps=cs)
    return headline_files(run, out)


def headline_files(run: Path, out: Path | None = None) -> dict[str, str]:
    """The scorecard's headline files: those of :data:`EVALUATED` under ``out`` (the run's own
    when None), the others the run's."""
    res = run / "results"
    files = layout.headline_files(str(res), str(res))
    return {**files, **({k: str(out / layout.PER_NETWORKS[k]) for k in EVALUATED} if out else {})}


def headline_ratios(files: dict[str, str]) -> dict[str, float]:
    """:data:`HEADLINES` of the scorecard read from ``files``, as ratios to the paper."""
    from cvsim6.reporting import scorecard as sc

    values, rows = sc.headline_values(files)
    by_key = {h.key: h for h in rows}
    return {f"{k} / paper": sc.ratio_to_paper(values[k], by_key[k]) for k in HEADLINES}


def training_summary(losses: Path, restart_epochs: int) -> dict:
    """Best test loss, its epoch and the CPU seconds after the choice, from a losses CSV."""
    t = pd.read_csv(losses)
    best = t.loc[t["test_loss"].idxmin()]
    return {"best_epoch": int(best["epoch"]), "best_test_loss": float(best["test_loss"]),
            "continuation_cpu_s": float(t.loc[t["epoch"] > restart_epochs, "cpu_seconds"].sum())}


def main(argv: list[str] | None = None) -> pd.DataFrame:
    import results_io
    import torch

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True, help="a finished run's folder (its results/ beside config)")
    p.add_argument("--seed", type=int, default=None, help="the run's seed (default: the config's)")
    p.add_argument("--epochs", type=int, nargs="+", required=True, help="total epochs E of each continuation")
    p.add_argument("--work", type=Path, required=True, help="where the continuations go (kept: a rerun resumes)")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--config", type=Path, default=None, help="the run's config (default <run>/config/config.yaml)")
    p.add_argument("--name", default="continuation_epochs")
    results_io.add_note_argument(p)
    args = p.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/continuation_epochs.py", *argv])
    cfg = yaml.safe_load((args.config or args.run / "config" / "config.yaml").read_text())
    args.seed = int(cfg["seed"]) if args.seed is None else args.seed
    args.epochs = sorted(set(args.epochs))
    hyper = dict(cfg["training"]["studies"]["structural"]["encoder_decoder"])
    r = int(hyper["restart_epochs"])
    if min(args.epochs) <= r:
        raise ValueError(f"--epochs {min(args.epochs)}: the continuation starts at restart_epochs = {r}")
    res = args.run / "results"
    models, data = res / "models" / "structural", res / "data" / "structural"
    run_ckpt = torch.load(models / "encoder_decoder_delta0.pt.ckpt", map_location="cpu", weights_only=True)
    restart = run_ckpt["extra"]["restart"]
    cand = models / f"encoder_decoder_delta0.pt.ckpt.candidate{restart['chosen']}"
    run_row = {"model": "run", "epochs": int(hyper["epochs"]),
               **training_summary(res / "training" / "structural" / "encoder_decoder_delta0_losses.csv", r),
               **headline_ratios(evaluate(models / "encoder_decoder_delta0.pt", args.work / "run", args.run, cfg,
                                          args.seed))}
    off = {k: [run_row[k], v] for k, v in headline_ratios(headline_files(args.run)).items()
           if not math.isclose(run_row[k], v, rel_tol=1e-9)}
    if off:  # another config, code or floating-point path than the run's: the rows are not comparable
        print(f"WARNING: the run's model evaluated here differs from its own headline files: {off}", file=sys.stderr)
    jobs = [(e, args.work / f"epochs{e}", data, models / "emulator.pt", hyper, args.seed, cand, restart)
            for e in args.epochs]
    with mp.get_context("spawn").Pool(min(args.jobs, len(jobs))) as pool:
        trained = {e: (cpu, n) for e, cpu, n in pool.imap_unordered(continue_candidate, jobs)}
    rows = [run_row]
    for e in args.epochs:
        out = args.work / f"epochs{e}"
        rows.append({"model": "continued here", "epochs": e,
                     **training_summary(out / "encoder_decoder_delta0_losses.csv", r),
                     **headline_ratios(evaluate(out / "models" / "encoder_decoder_delta0.pt", out, args.run, cfg,
                                                args.seed))})
    table = pd.DataFrame(rows)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(table.to_string(index=False, float_format="%.4g"))
    run.save(args.name, f"Epochs of the structural encoder/decoder's continuation, seed {args.seed}",
             f"The chosen restart candidate (candidate {restart['chosen']}) of a run with seed {args.seed}, continued "
             f"from its checkpoint at epoch {r} under the config's schedule shortened to E epochs (one thread each), "
             "then evaluated as the workflow does (the run's flow, emulator, y* and seed); the row 'run' is the run's "
             "own model. Headlines as ratios to the paper (SVD: modes over the paper's 12). continuation_cpu_s: the "
             "epochs after the choice, from the losses CSV; best_epoch and best_test_loss: the kept weights.",
             [results_io.table(table, "continuations", "Per total epochs E.", FORMATS)],
             parameters={"run": results_io.portable(str(args.run.resolve())), "seed": args.seed, "epochs": args.epochs,
                         "chosen_candidate": restart["chosen"], "restart_epochs": r, "hyper": hyper,
                         "trained_here": {str(e): {"cpu_s": c, "epochs": n} for e, (c, n) in trained.items()},
                         "run_row_differs_from_run": off},
             note=args.note)
    return table


if __name__ == "__main__":
    main()
