"""Benchmark: held-out error reached against CPU seconds, our schedule vs the paper's.

For one study and one network, trains the same architecture on the same data from the same
seed under several schedules, each for the same CPU-time budget (one thread per process,
``--jobs`` processes side by side), and prints the held-out error each reached at fractions of
the budget. Schedules: ``ours`` (config/config.yaml), ``paper`` (config/paper.yaml, cut off
at the budget, so its learning rate has decayed less), and any ``--variant NAME='{yaml}'``
(keys merged onto ``ours``, e.g. a cosine schedule or float64). A schedule whose loss turns
non-finite stops there; its table row names that epoch (``diverged at epoch``, 0: none).

Held-out error: the loss on the test split (12,500 rows, never trained on), per network --
emulator: MSE of the standardized outputs; flow: negative log-likelihood (nats); encoder/decoder:
the unweighted decoder term (MSE of the standardized parameters). The encoder/decoder trains
through a fixed emulator file (``--emulator``, default the workflow's).

    .venv/bin/python benchmarks/training.py --study structural --network emulator --seconds 600 \
        --variant 'cosine={lr_schedule: cosine, warmup_epochs: 20, lr_final: 0.0}'

Writes ``benchmarks/results/training_<study>_<network>[_delta<d>].json``: the best held-out
error of each schedule within fractions of the budget, and each schedule's best-so-far curve
(at most ``CURVE_POINTS`` points). ``--losses FILE.csv`` also writes every epoch's losses (one
row per epoch and schedule), ``--figure FILE.png`` a plot of the curves.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
#: Points kept of each schedule's best-so-far curve in the result file.
CURVE_POINTS = 100
METRIC = {"emulator": ("test_loss", "held-out MSE (standardized outputs)"),
          "flow": ("test_loss", "held-out NLL (nats)"),
          "encoder_decoder": ("test_decoder", "held-out decoder MSE (standardized parameters)")}


def schedule(config_file: Path, study: str, network: str) -> dict:
    """Hyperparameters of ``network`` in ``study`` from a workflow config file, with one
    initialization: ``restarts``/``restart_epochs`` are dropped, so every schedule's curve is one
    training from the seed (restart candidate 0) and its losses file fills from the first epoch."""
    h = dict(yaml.safe_load(config_file.read_text())["training"]["studies"][study][network])
    h.pop("restarts", None)
    h.pop("restart_epochs", None)
    return h


def _run(job: tuple) -> pd.DataFrame:
    from cvsim6.training import train as training

    name, study, network, hyper, seconds, seed, delta, emulator = job
    data = ROOT / "results" / "data" / study
    with tempfile.TemporaryDirectory() as tmp:
        out = {k: str(Path(tmp) / f) for k, f in (("model", "m.pt"), ("losses", "l.csv"))}
        common = dict(train=str(data / "train.parquet"), test=str(data / "test.parquet"), hyper=hyper, seed=seed,
                      device="cpu", threads=1, progress=False, max_cpu_seconds=seconds, checkpoint_every=10**9, **out)
        diverged = False
        try:
            if network == "emulator":
                training.train_emulator(**common)
            elif network == "flow":
                training.train_flow(noise_level=delta, **common)
            else:
                training.train_encoder_decoder(emulator=emulator, noise_level=delta, **common)
        except FloatingPointError as exc:  # diverged: its losses file ends with the failed epoch
            print(f"{name}: {exc}")
            diverged = True
        df = pd.read_csv(out["losses"])
    df.insert(0, "schedule", name)
    df["diverged_at_epoch"] = int(df["epoch"].iloc[-1]) if diverged else 0
    df["cpu_seconds_total"] = df["cpu_seconds"].cumsum()
    return df


def reached(df: pd.DataFrame, metric: str, fractions: list[float], budget: float) -> pd.DataFrame:
    """Best held-out error of each schedule within each fraction of the CPU budget."""
    rows = []
    for name, g in df.groupby("schedule", sort=False):
        diverged_at = int(g["diverged_at_epoch"].max())  # one value per schedule
        g = g[np.isfinite(g[metric])]
        row = {"schedule": name, "epochs": int(g["epoch"].max()) if len(g) else 0, "diverged at epoch": diverged_at}
        for f in fractions:
            within = g[g["cpu_seconds_total"] <= f * budget * 1.02][metric]
            row[f"{f:g} x budget"] = float(within.min()) if len(within) else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def curves(df: pd.DataFrame, metric: str, points: int = CURVE_POINTS) -> pd.DataFrame:
    """Each schedule's best-so-far held-out error against its cumulative CPU seconds, at most
    ``points`` rows per schedule: the epochs where the best improved, evenly thinned, the last
    epoch always kept."""
    parts = []
    for name, g in df.groupby("schedule", sort=False):
        g = g[np.isfinite(g[metric])]
        if g.empty:
            continue
        best = g[metric].cummin()
        keep = g[best.diff().fillna(-1.0).lt(0.0).to_numpy()].index.append(g.index[-1:]).unique()
        if len(keep) > points:
            keep = keep[np.unique(np.linspace(0, len(keep) - 1, points).round().astype(int))]
        parts.append(pd.DataFrame({"schedule": name, "epoch": g.loc[keep, "epoch"].astype(int),
                                   "cpu_seconds_total": g.loc[keep, "cpu_seconds_total"],
                                   f"best_{metric}": best[keep]}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def plot(df: pd.DataFrame, metric: str, label: str, title: str, path: Path) -> None:
    """The best-so-far curves of the schedules, to ``path`` (no pyplot: no backend chosen)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    for name, g in df.groupby("schedule", sort=False):
        g = g[np.isfinite(g[metric])]
        ax.plot(g["cpu_seconds_total"], g[metric].cummin(), label=name, lw=1.3)
    if (df[metric].dropna() > 0).all():
        ax.set_yscale("log")
    ax.set_xlabel("CPU seconds (one thread)")
    ax.set_ylabel(f"best {label}")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", choices=["structural", "ehr"], default="structural")
    ap.add_argument("--network", choices=sorted(METRIC), default="emulator")
    ap.add_argument("--seconds", type=float, default=600.0, help="CPU seconds per schedule")
    ap.add_argument("--delta", type=float, default=None, help="training noise level (default: the study's first)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--jobs", type=int, default=2, help="schedules trained side by side (one thread each)")
    ap.add_argument("--emulator", default=None, help="emulator file for the encoder/decoder")
    ap.add_argument("--no-paper", action="store_true", help="skip the paper's schedule")
    ap.add_argument("--no-ours", action="store_true", help="skip our schedule (variants still build on it)")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=YAML",
                    help="a schedule: these keys merged onto ours (repeatable)")
    ap.add_argument("--losses", type=Path, default=None, help="also write every epoch's losses to this CSV")
    ap.add_argument("--figure", type=Path, default=None, help="also plot the curves to this PNG")
    import results_io

    results_io.add_note_argument(ap)
    args = ap.parse_args()
    run = results_io.Run()

    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())["training"]["studies"][args.study]
    delta = float(cfg["noise_levels"][0] if args.delta is None else args.delta)
    emulator = args.emulator or str(ROOT / "results" / "models" / args.study / "emulator.pt")
    ours = schedule(ROOT / "config" / "config.yaml", args.study, args.network)
    schedules = {} if args.no_ours else {"ours": ours}
    if not args.no_paper:
        schedules["paper"] = schedule(ROOT / "config" / "paper.yaml", args.study, args.network)
    for v in args.variant:
        name, _, text = v.partition("=")
        schedules[name] = {**ours, **(yaml.safe_load(text) or {})}

    jobs = [(n, args.study, args.network, h, args.seconds, args.seed, delta, emulator) for n, h in schedules.items()]
    with mp.get_context("spawn").Pool(min(args.jobs, len(jobs))) as pool:
        df = pd.concat(pool.map(_run, jobs), ignore_index=True)

    stem = f"training_{args.study}_{args.network}" + (f"_delta{delta:g}" if args.network != "emulator" else "")
    if args.losses:
        df.to_csv(args.losses, index=False)
    metric, label = METRIC[args.network]
    table = reached(df, metric, [0.25, 0.5, 1.0], args.seconds)
    print(f"{args.study} {args.network} (delta={delta:g}), {args.seconds:g} CPU-s per schedule; best {label}:")
    print(table.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    for name, h in schedules.items():
        print(f"  {name}: {h}")
    title = f"{args.study} {args.network}" + (f", delta={delta:g}" if args.network != "emulator" else "")
    if args.figure:
        plot(df, metric, label, title, args.figure)
    run.save(
        stem, f"Training: held-out error against CPU seconds ({title})",
        f"The {args.study} study's {args.network} trained from the same seed and data under each schedule for "
        f"the same CPU budget (one thread each, side by side): our schedule (config/config.yaml), the paper's "
        f"(config/paper.yaml, cut off at the budget) and any variant (keys merged onto ours). Best {label} "
        f"reached within fractions of the budget; the curves are in the file.",
        [results_io.table(table, "reached", f"Best {label} within each fraction of the CPU budget per schedule.",
                          {c: ".4g" for c in table.columns if c not in ("schedule", "epochs", "diverged at epoch")}),
         results_io.table(curves(df, metric), "curves", f"Best-so-far {label} against CPU seconds, per schedule "
                          f"(thinned).", {}, page=False)],
        parameters={"study": args.study, "network": args.network, "cpu_seconds_per_schedule": args.seconds,
                    "noise_level": delta, "seed": args.seed, "jobs": args.jobs, "schedules": schedules},
        note=args.note)


if __name__ == "__main__":
    main()
