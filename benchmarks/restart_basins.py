"""Benchmark: which restart candidates of the structural encoder/decoder find every latent
direction by the choice epoch, and what tells them apart?

The workflow trains ``restarts`` initializations of the structural encoder/decoder to epoch
``restart_epochs`` and continues the one with the lowest test loss there
(:mod:`cvsim6.training.restarts`). A candidate either reaches the basin where the encoder uses
every latent direction it needs, or one where it is one or two short (decision 0014). This
script trains further candidates of a finished run (candidate c's seed is
:func:`cvsim6.seeding.candidate_seed` of the run's seed and c, so they are the candidates a run
with more restarts would train, bit for bit) and describes each at the choice epoch:

- ``test_loss``: the criterion the workflow ranks by; ``test_decoder``: its decoder term (MSE of
  the standardized parameters, w drawn from the encoder);
- ``kl_nats``: the KL term; per latent dimension, the mean KL over the test rows: ``dims_used``
  counts dimensions above ``USED_NATS``, ``kl_max_over_median`` the largest over the median of
  those (an overloaded direction carries the work of two);
- ``decoder_mse_mean_w``: the decoder's MSE with w = the encoder's mean, mean and worst parameter
  (:meth:`cvsim6.training.stages.EncoderDecoderStage.reconstruction_errors`, the workflow's
  ``restart_target`` criterion).

Candidates the run already has (``<models>/encoder_decoder_delta0.pt.ckpt.candidate<c>``) are read,
not retrained. Others are trained here (one thread each, ``--jobs`` side by side) into ``--work``,
which keeps their checkpoints: a rerun resumes or reads them.

    .venv/bin/python benchmarks/restart_basins.py --run <run> --seed 2024 --candidates 0-8 \\
        --work <scratch>/2024

Output: the table on stdout, and ``benchmarks/results/restart_basins.json`` (``--name`` for another).
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time
from pathlib import Path

if __name__ == "__main__":  # one BLAS thread per process (not when a test imports this)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: A latent dimension is in use when its mean KL over the test rows exceeds this (nats).
USED_NATS = 0.5
FORMATS = {"test_loss": ".1f", "test_decoder": ".4f", "kl_nats": ".2f", "kl_max_over_median": ".2f",
           "decoder_mse_mean_w": ".4f", "decoder_mse_worst_parameter": ".4f", "cpu_seconds": ".0f"}


def parse_candidates(text: str) -> list[int]:
    """``"0-8"`` or ``"3,5,7"`` (or a mix, ``"0-2,6"``) as a sorted list of candidate indices."""
    out: set[int] = set()
    for part in text.split(","):
        a, _, b = part.strip().partition("-")
        out.update(range(int(a), int(b or a) + 1))
    return sorted(out)


def latent_usage(kl_per_dim: np.ndarray, used_nats: float = USED_NATS) -> dict:
    """Dimensions in use (mean KL above ``used_nats``) and the largest one's KL over the median
    of those in use (NaN when none is)."""
    used = kl_per_dim[kl_per_dim > used_nats]
    return {"dims_used": int(used.size),
            "kl_max_over_median": float(used.max() / np.median(used)) if used.size else float("nan")}


def describe(checkpoint: Path, hyper: dict, data: Path, emulator: Path) -> dict:
    """A candidate's state at its checkpoint (see the module docstring)."""
    import torch

    from cvsim6 import nets as nw
    from cvsim6.data.datasets import load_split
    from cvsim6.training.stages import EncoderDecoderStage
    from cvsim6.training.train import encoder_decoder_net

    ck = torch.load(checkpoint, map_location="cpu", weights_only=True)
    v_tr, y_tr = load_split(str(data / "train.parquet"))
    v_te, y_te = load_split(str(data / "test.parquet"))
    mask = ck["model"].get("x_scaler.log_mask")
    log_cols = [] if mask is None else [int(i) for i in torch.nonzero(mask.bool()).flatten().tolist()]
    net = encoder_decoder_net(hyper, log_cols)
    net.load_state_dict(ck["model"])
    net.eval()
    emu = nw.load_model(str(emulator))
    stage = EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                                net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), 0.0, hyper,
                                torch.Generator().manual_seed(0), torch.device("cpu"))
    err = stage.reconstruction_errors().numpy()
    with torch.no_grad():
        mu, logvar = net.encode(stage.v_te)
        kl = (0.5 * (mu * mu + torch.exp(logvar) - logvar - 1.0)).mean(dim=0).double().numpy()
    row = next(r for r in ck["history"] if int(r["epoch"]) == int(ck["epoch"]))
    return {"epoch": int(ck["epoch"]), "test_loss": float(row["test_loss"]), "test_decoder": float(row["test_decoder"]),
            "kl_nats": float(kl.sum()), **latent_usage(kl), "decoder_mse_mean_w": float(err.mean()),
            "decoder_mse_worst_parameter": float(err.max()),
            "cpu_seconds": float(sum(float(r.get("cpu_seconds") or 0.0) for r in ck["history"])),
            "kl_per_dim": [round(float(x), 4) for x in np.sort(kl)[::-1]]}


def _train(job: tuple) -> tuple[int, float]:
    """Train candidate ``c`` to the choice epoch (or resume / read it); its CPU seconds here."""
    from cvsim6.training import train as training

    c, data, emulator, hyper, seed, ckpt = job
    t0 = time.process_time()
    training.train_encoder_decoder(train=str(data / "train.parquet"), test=str(data / "test.parquet"),
                                   emulator=str(emulator), model=str(ckpt) + ".model", losses=str(ckpt) + ".csv",
                                   hyper=hyper, seed=seed, device="cpu", threads=1, checkpoint=str(ckpt),
                                   progress=False, candidate=c)
    return c, time.process_time() - t0


def main(argv: list[str] | None = None) -> pd.DataFrame:
    import results_io

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True, help="a finished run's folder (its results/ beside config)")
    p.add_argument("--seed", type=int, default=2024, help="the run's seed")
    p.add_argument("--models", type=Path, default=None,
                   help="the run's structural models folder (default <run>/results/models/structural)")
    p.add_argument("--candidates", type=parse_candidates, default=parse_candidates("0-2"))
    p.add_argument("--work", type=Path, required=True, help="where new candidates' checkpoints go (kept)")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    p.add_argument("--name", default="restart_basins")
    results_io.add_note_argument(p)
    args = p.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/restart_basins.py", *argv])
    hyper = dict(yaml.safe_load(args.config.read_text())["training"]["studies"]["structural"]["encoder_decoder"])
    hyper["restarts"] = max(int(hyper.get("restarts", 1)), max(args.candidates) + 1)
    for key in ("restart_target", "max_restarts"):  # each candidate trains alone: no screening
        hyper.pop(key, None)
    from cvsim6.training.hyperparameters import check_hyper

    hyper = check_hyper("encoder_decoder", hyper)
    models = args.models or args.run / "results" / "models" / "structural"
    data = args.run / "results" / "data" / "structural"
    args.work.mkdir(parents=True, exist_ok=True)
    paths, jobs = {}, []
    for c in args.candidates:
        own = models / f"encoder_decoder_delta0.pt.ckpt.candidate{c}"
        paths[c] = own if own.exists() else args.work / f"candidate{c}"
        if not own.exists():
            jobs.append((c, data, models / "emulator.pt", hyper, args.seed, paths[c]))
    trained = {}
    if jobs:
        with mp.get_context("spawn").Pool(min(args.jobs, len(jobs))) as pool:
            trained = dict(pool.imap_unordered(_train, jobs))
    from cvsim6.seeding import candidate_seed

    rows = []
    for c in args.candidates:
        d = describe(paths[c], hyper, data, models / "emulator.pt")
        rows.append({"seed": args.seed, "candidate": c, "candidate_seed": candidate_seed(args.seed, c),
                     "source": "run" if paths[c].parent == models else "trained here", **d})
    table = pd.DataFrame(rows)
    shown = table.drop(columns=["kl_per_dim"])
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(shown.to_string(index=False, float_format="%.4g"))
    run.save(args.name, f"Restart candidates of the structural encoder/decoder, seed {args.seed}",
             f"Candidates {args.candidates[0]}-{args.candidates[-1]} of the structural encoder/decoder of a run with "
             f"seed {args.seed}, each at the choice epoch ({hyper.get('restart_epochs')}), trained on the run's data "
             f"through its emulator with the config's hyperparameters (one thread each). test_loss is the "
             f"workflow's criterion; dims_used counts latent dimensions with a mean KL over the test rows above "
             f"{USED_NATS} nats; kl_max_over_median is the largest of those over their median; decoder_mse_mean_w "
             f"the decoder's MSE of the standardized parameters with w the encoder's mean (mean and worst "
             f"parameter). cpu_seconds: the candidate's training, from its losses.",
             [results_io.table(table, "candidates", "Per candidate at the choice epoch.", FORMATS)],
             parameters={"run": results_io.portable(str(args.run.resolve())), "seed": args.seed,
                         "candidates": args.candidates, "hyper": hyper, "used_nats": USED_NATS,
                         "trained_here_cpu_s": trained},
             note=args.note)
    return table


if __name__ == "__main__":
    main()
