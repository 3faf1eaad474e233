"""Command-line interface: ``cvsim6 simulate PARAMS.csv -o OUT.csv``.

``PARAMS.csv`` has a header with the 23 parameter names (clinical units, any column
order, extra columns ignored); ``OUT.csv`` has the 16 outputs plus ``status``, one
row per input row, in the same order.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import pandas as pd

from . import __version__
from .model import ParameterError


def _simulate(args: argparse.Namespace) -> int:
    from .solver import simulate

    try:
        params = pd.read_csv(args.params)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        print(f"error: cannot read {args.params}: {exc}", file=sys.stderr)
        return 2
    try:
        df = simulate(params, method=args.method, steps_per_cycle=args.steps_per_cycle,
                      progress=args.progress)
    except ParameterError as exc:
        print(f"error: {args.params}: {exc}", file=sys.stderr)
        return 2
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(out, index=False, float_format="%.10g")
    n_bad = int((df["status"] != "ok").sum())
    msg = f"simulated {len(df)} parameter set(s) -> {out}"
    if n_bad:
        msg += f" ({n_bad} flagged, see the status column)"
    print(msg, file=sys.stderr)
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
    return parser


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
