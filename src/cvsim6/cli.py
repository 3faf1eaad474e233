"""Command-line interface of the CVSim-6 digital twin.

``cvsim6 simulate PARAMS.csv -o OUT.csv``: PARAMS.csv has a header with the 23
parameter names (clinical units, any column order, extra columns ignored); OUT.csv
has the 16 outputs plus ``status``, one row per input row, in the same order.

``cvsim6 invert OBS.csv -o PARAMS.csv``: OBS.csv has any subset of the 16 output
names as columns, one patient per row (blank = missing; an optional ``patient``
column names them); PARAMS.csv has, per patient, the sampled parameter sets with
their emulated outputs (``pred_*``) and the patient's out-of-distribution percentile.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import pandas as pd

from . import __version__
from .model import ParameterError


def _read_csv(path: str) -> pd.DataFrame | None:
    """The CSV at ``path``, or None after printing why it cannot be read."""
    try:
        return pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        print(f"error: cannot read {path}: {exc}", file=sys.stderr)
        return None


def _write_csv(df: pd.DataFrame, path: str, float_format: str) -> Path:
    """Write ``df`` to ``path`` (parent folders created); returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(out, index=False, float_format=float_format)
    return out


def _simulate(args: argparse.Namespace) -> int:
    from .solver import simulate

    params = _read_csv(args.params)
    if params is None:
        return 2
    try:
        df = simulate(params, method=args.method, steps_per_cycle=args.steps_per_cycle,
                      progress=args.progress)
    except ParameterError as exc:
        print(f"error: {args.params}: {exc}", file=sys.stderr)
        return 2
    out = _write_csv(df, args.output, "%.10g")
    n_bad = int((df["status"] != "ok").sum())
    msg = f"simulated {len(df)} parameter set(s) -> {out}"
    if n_bad:
        msg += f" ({n_bad} flagged, see the status column)"
    print(msg, file=sys.stderr)
    return 0


def _invert(args: argparse.Namespace) -> int:
    import numpy as np

    from .ehr_study import invert_observations
    from .networks import load_model

    models = Path(args.models)
    tag = f"{args.noise_level:g}"
    files = {"emulator": models / "emulator.pt", "flow": models / f"flow_delta{tag}.pt",
             "encoder_decoder": models / f"encoder_decoder_delta{tag}.pt"}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        print(f"error: model file(s) not found: {', '.join(missing)} (train them with the workflow, "
              f"or pass --models and --noise-level)", file=sys.stderr)
        return 2
    obs = _read_csv(args.observations)
    if obs is None:
        return 2
    if "patient" in obs.columns:
        obs = obs.set_index("patient")
    try:
        obs = obs.apply(pd.to_numeric, errors="raise")
    except (ValueError, TypeError) as exc:
        print(f"error: {args.observations}: a value is not a number: {exc}", file=sys.stderr)
        return 2
    flow = load_model(files["flow"])
    if args.reference:
        from .datasets import load_split

        ref = load_split(args.reference)[1]
    else:  # the flow's own samples stand in for simulated outputs
        ref = flow.sample_physical(2000)
        ref = ref[np.isfinite(ref).all(axis=1)]
    try:
        df = invert_observations(obs, flow, load_model(files["encoder_decoder"]),
                                 load_model(files["emulator"]), n_latent=args.samples,
                                 n_flow_samples=args.flow_samples, seed=args.seed, reference_outputs=ref,
                                 n_reference=args.reference_size, progress=args.progress,
                                 corrector_steps=args.corrector_steps)
    except ValueError as exc:
        print(f"error: {args.observations}: {exc}", file=sys.stderr)
        return 2
    out = _write_csv(df.rename(columns={"id": "patient"}), args.output, "%.8g")
    print(f"inverted {df['id'].nunique()} patient(s) x {args.samples} samples -> {out}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cvsim6", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="simulate parameter sets to the 16 clinical outputs")
    sim.add_argument("params", help="CSV with the 23 parameter names as header (clinical units)")
    sim.add_argument("-o", "--output", required=True, help="output CSV: 16 outputs + status")
    sim.add_argument("--method", choices=("batch", "reference"), default="batch",
                     help="batch: fast fixed-step SDIRK (default); reference: scipy Radau, slow")
    sim.add_argument("--steps-per-cycle", type=int, default=600,
                     help="time steps per cardiac cycle of the batch solver (default 600)")
    sim.add_argument("--progress", action="store_true", help="show a progress bar")
    sim.set_defaults(func=_simulate)
    inv = sub.add_parser("invert", help="infer parameter sets of patients from (partial) observations")
    inv.add_argument("observations", help="CSV: any of the 16 output names as columns, one patient per row")
    inv.add_argument("-o", "--output", required=True, help="output CSV: samples, emulated outputs, OOD")
    inv.add_argument("--models", default="results/models/ehr",
                     help="folder with emulator.pt, flow_delta<d>.pt, encoder_decoder_delta<d>.pt")
    inv.add_argument("--noise-level", type=float, default=0.5, help="training-noise level delta (default 0.5)")
    inv.add_argument("--samples", type=int, default=100, help="latent draws per patient (default 100)")
    inv.add_argument("--flow-samples", type=int, default=200_000,
                     help="flow samples ranked to complete missing outputs (paper: 5.1 million)")
    inv.add_argument("--reference", help="Parquet split of simulated data for the OOD percentile "
                                          "(default: samples of the flow)")
    inv.add_argument("--reference-size", type=int, default=100, help="reference rows for the OOD percentile")
    inv.add_argument("--corrector-steps", type=int, default=2,
                     help="predictor-corrector rounds when decoding (default 2, as the paper's code; 0 = off)")
    inv.add_argument("--seed", type=int, default=0)
    inv.add_argument("--progress", action="store_true", help="show a progress bar")
    inv.set_defaults(func=_invert)
    return parser


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
