"""Benchmark: how long the networks of a config take to train on this machine, before a long run.

Trains each network of a workflow config (default ``config/config.yaml``) for a few epochs
through the workflow's own training code (one thread, as the rules run it), on synthetic data
of the config's split sizes: a few hundred simulated parameter sets from the study's prior,
repeated to the training and test sizes (the cost of an epoch depends on the sizes, not the
values). Prints, per network, the CPU seconds per epoch measured here, the same for a timed
run on the development machine (commit ``bfc86cf``, its ``benchmarks/`` per rule divided by
its epochs) and the ratio, and estimates the training's CPU seconds for the whole config and
the wall time on ``--cores`` cores. An estimate, not a run: it leaves out simulation and the study rules (about
5% of the timed run's CPU time) and scheduling gaps.

    .venv/bin/python benchmarks/machine_speed.py
    .venv/bin/python benchmarks/machine_speed.py --configfile config/paper.yaml --epochs 3

Writes ``benchmarks/results/machine_speed.json`` (``machine_speed_<config>.json`` for another
config file than ``config/config.yaml``).
"""
from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
NETWORKS = ("emulator", "flow", "encoder_decoder")
#: CPU seconds per epoch of each network in a timed run of the default config on the development machine
#: (commit ``bfc86cf``, seed 2024, 2 cores): that run's benchmarks/ per rule over its epochs
#: (structural emulator 1,452 CPU-s / 5,400 epochs, encoder/decoder 4,224 / 7,200, flow 543 /
#: 600; EHR emulator 1,927 / 6,000, encoder/decoders 420-450 / 800, flows 245-300 / 400).
TIMED_RUN_CPU_PER_EPOCH = {
    ("structural", "emulator"): 1452 / 5400, ("structural", "encoder_decoder"): 4224 / 7200,
    ("structural", "flow"): 543 / 600, ("ehr", "emulator"): 1927 / 6000,
    ("ehr", "encoder_decoder"): 435 / 800, ("ehr", "flow"): 272 / 400,
}


def split_sizes(study_data: dict) -> tuple[int, int]:
    """Training and test rows of a study's ``data.studies.<study>`` config entry (no failed runs)."""
    split = study_data["split"]
    rest = int(study_data["n_samples"]) - int(split["validation"])
    n_train = int(round(rest * float(split["train_fraction"])))
    return n_train, rest - n_train


def candidates(hyper: dict, screened: bool = False) -> int:
    """Restart candidates one network trains: ``restarts``; with ``screened``, as many as a
    ``restart_target`` that no candidate meets makes the job screen (``max_restarts``)."""
    k = int(hyper.get("restarts", 1))
    most = hyper.get("max_restarts")
    return int(most) if screened and hyper.get("restart_target") is not None and most is not None else k


def schedule_epochs(hyper: dict, screened: bool = False) -> int:
    """Epochs one network trains, restart candidates included: each candidate (see
    ``candidates``) trains the first ``restart_epochs``, the chosen one continues to ``epochs``."""
    extra = (candidates(hyper, screened) - 1) * int(hyper.get("restart_epochs", 0))
    return int(hyper["epochs"]) + max(extra, 0)


def estimate(per_epoch: dict, training: dict, cores: int, screened: bool = False) -> tuple[pd.DataFrame, float, float]:
    """Per network (study, network): copies (noise levels), epochs, CPU-s; the total CPU-s; and
    the wall time on ``cores`` cores: the longer of the total over the cores and the structural
    chain (emulator, then the encoder/decoder with its ``restarts`` candidates side by side when
    cores allow and, with ``screened``, the extra candidates up to ``max_restarts`` one at a time)."""
    rows = []
    for (study, network), s in per_epoch.items():
        h = training["studies"][study][network]
        copies = 1 if network == "emulator" else len(training["studies"][study]["noise_levels"])
        epochs = schedule_epochs(h, screened)
        rows.append({"study": study, "network": network, "copies": copies, "epochs": epochs,
                     "cpu_s_per_epoch": s, "cpu_s": s * epochs * copies})
    df = pd.DataFrame(rows)
    total = float(df["cpu_s"].sum())
    structural = training["studies"]["structural"]
    h = structural["encoder_decoder"]
    restarts = int(h.get("restarts", 1))
    first = int(h.get("restart_epochs", 0)) if restarts > 1 else 0
    waves = math.ceil(restarts / cores) if restarts > 1 else 0  # rounds of candidates side by side
    waves += candidates(h, screened) - restarts  # screened candidates, one at a time in the training job
    chain = (per_epoch.get(("structural", "emulator"), 0.0) * int(structural["emulator"]["epochs"])
             + per_epoch.get(("structural", "encoder_decoder"), 0.0) * (waves * first + int(h["epochs"]) - first))
    return df, total, max(total / cores, chain)


def _synthetic_splits(study: str, cfg: dict, folder: Path, n_unique: int, seed: int) -> tuple[Path, Path]:
    from cvsim6.data import datasets
    from cvsim6.data import priors
    from cvsim6 import registry
    from cvsim6.model import solver

    data = cfg["data"]["studies"][study]
    lo, hi = priors.prior_bounds(data["prior"])
    v = priors.sample_uniform(lo, hi, n_unique, np.random.default_rng(seed))
    y, status = solver.simulate_batch(v, steps_per_cycle=int(cfg["simulator"]["steps_per_cycle"]))
    v, y = v[status == 0], y[status == 0]
    paths = []
    for name, n in zip(("train", "test"), split_sizes(data)):
        rows = np.arange(n) % len(v)
        df = pd.DataFrame(v[rows], columns=list(registry.PARAMETER_NAMES))
        for j, out in enumerate(registry.OUTPUT_NAMES):
            df[out] = y[rows, j]
        paths.append(folder / f"{study}_{name}.parquet")
        datasets.write_dataset(df, paths[-1])
    return paths[0], paths[1]


def measure(study: str, network: str, cfg: dict, train: Path, test: Path, folder: Path, epochs: int,
            seed: int) -> float:
    """CPU seconds per epoch of ``network``, over ``epochs`` epochs (at least one test evaluation)."""
    from cvsim6.data import datasets
    from cvsim6 import nets as networks
    from cvsim6.training import train as training
    from cvsim6.training.hyperparameters import check_hyper

    h = dict(cfg["training"]["studies"][study][network])
    for key in ("restarts", "restart_epochs", "restart_target", "max_restarts"):  # one candidate's epochs
        h.pop(key, None)
    n = max(epochs, int(h.get("eval_every", 1)))
    delta = float(cfg["training"]["studies"][study]["noise_levels"][0])
    out = dict(model=str(folder / f"{study}_{network}.pt"), losses=str(folder / f"{study}_{network}.csv"),
               hyper=h, seed=seed, device="cpu", threads=1, progress=False, max_epochs_this_run=n,
               checkpoint_every=10**9, train=str(train), test=str(test))
    if network == "emulator":
        training.train_emulator(**out)
    elif network == "flow":
        training.train_flow(noise_level=delta, **out)
    else:  # through an untrained emulator of the config's architecture (the cost is the same)
        he = check_hyper("emulator", cfg["training"]["studies"][study]["emulator"])
        v, y = datasets.load_split(train)
        emu = networks.Emulator(he["hidden"], he["layers"], activation=he["activation"])
        emu.x_scaler.fit(v)
        emu.y_scaler.fit(y)
        networks.save_model(emu, folder / f"{study}_emulator_frozen.pt", info={"stage": "emulator"})
        training.train_encoder_decoder(emulator=str(folder / f"{study}_emulator_frozen.pt"), noise_level=delta, **out)
    losses = pd.read_csv(out["losses"])
    return float(losses["cpu_seconds"].mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configfile", default=str(ROOT / "config" / "config.yaml"),
                    help="workflow config whose networks to time (keys merged onto config/config.yaml)")
    ap.add_argument("--epochs", type=int, default=10, help="epochs per network (at least one evaluation)")
    ap.add_argument("--cores", type=int, default=2, help="cores of the run to estimate")
    ap.add_argument("--rows", type=int, default=400, help="distinct simulated sets per study")
    ap.add_argument("--seed", type=int, default=2024)
    import results_io

    results_io.add_note_argument(ap)
    args = ap.parse_args()
    run = results_io.Run()

    import torch

    torch.set_num_threads(1)
    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    other = yaml.safe_load(Path(args.configfile).read_text()) or {}
    for key in ("training", "data", "simulator"):  # Snakemake merges config files key by key
        if key in other:
            _merge(cfg[key], other[key])
    per_epoch, started = {}, time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for study in cfg["training"]["studies"]:
            train, test = _synthetic_splits(study, cfg, folder, args.rows, args.seed)
            for network in NETWORKS:
                per_epoch[(study, network)] = measure(study, network, cfg, train, test, folder, args.epochs, args.seed)
                print(f"  {study} {network}: {per_epoch[(study, network)]:.3f} CPU-s per epoch", flush=True)
    df, total, wall = estimate(per_epoch, cfg["training"], args.cores)
    _, total_screened, wall_screened = estimate(per_epoch, cfg["training"], args.cores, screened=True)
    df["timed_run_cpu_s_per_epoch"] = [TIMED_RUN_CPU_PER_EPOCH.get((s, n), math.nan) for s, n in
                                       zip(df["study"], df["network"])]
    df["ratio_to_timed_run"] = df["cpu_s_per_epoch"] / df["timed_run_cpu_s_per_epoch"]
    print(f"\n{Path(args.configfile).name}: per network, this machine against the development machine's timed run "
          f"(measured in {time.perf_counter() - started:.0f} s)")
    print(df.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    print(f"\ntraining: {total:,.0f} CPU-s estimated; on {args.cores} cores at least {wall / 60:.0f} minutes wall "
          f"(the longer of the total over the cores and the structural chain; simulation, the study rules and "
          f"scheduling gaps not counted)")
    if wall_screened > wall:
        print(f"with every restart candidate up to max_restarts screened: {total_screened:,.0f} CPU-s, "
              f"at least {wall_screened / 60:.0f} minutes wall")
    config = Path(args.configfile).resolve()
    name = "machine_speed" if config == (ROOT / "config" / "config.yaml").resolve() else f"machine_speed_{config.stem}"
    totals = pd.DataFrame({"quantity": ["training CPU seconds (estimate)", "cores",
                                        "wall minutes on those cores, at least (estimate)",
                                        "training CPU seconds, every candidate to max_restarts screened",
                                        "wall minutes, every candidate to max_restarts screened"],
                           "value": [total, args.cores, wall / 60, total_screened, wall_screened / 60]})
    run.save(
        name, f"Training cost per network ({config.name})",
        f"Each network of {results_io.portable(str(config))} trained for {args.epochs} epochs (at least one "
        f"evaluation) through the workflow's training code, one thread, on synthetic data of the config's split "
        f"sizes: CPU seconds per epoch; the epochs of the config's schedule (the restart candidates included; the "
        f"screened ones up to max_restarts in the last two rows of the estimate) and "
        f"copies (noise levels) give each network's CPU seconds. The timed run's column is a constant of "
        f"this script (a timed run on the development machine at commit bfc86cf, its per-job files per rule over its epochs), "
        f"not measured here. An estimate: simulation, the study rules and scheduling gaps are not counted.",
        [results_io.table(df, "networks", "CPU seconds per epoch per network, and for the config's schedule.",
                          {"cpu_s_per_epoch": ".3g", "cpu_s": ",.0f", "timed_run_cpu_s_per_epoch": ".3g",
                           "ratio_to_timed_run": ".2f"}),
         results_io.table(totals, "estimate", "The whole config's training.", {"value": ",.0f"})],
        parameters={"configfile": config, "epochs": args.epochs, "cores": args.cores, "rows": args.rows,
                    "seed": args.seed}, note=args.note)


def _merge(base: dict, new: dict) -> None:
    for k, v in new.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            _merge(base[k], v)
        else:
            base[k] = v


if __name__ == "__main__":
    main()
