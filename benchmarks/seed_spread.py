"""The reproduction scorecard of several runs side by side: how much of the gap is the seed's.

Each run is one ``snakemake all`` of the same config with another master seed (``--config
seed=2025``), in a checkout of its own; this reads each run's
``results/report/reproduction.csv`` (the ``trained`` column) and writes one row per headline:
the paper's value, each run's value and its ratio to the paper, and the spread of the ratios
(largest over smallest, a ratio >= 1).

    .venv/bin/python benchmarks/seed_spread.py seed2024=../run-a seed2025=../run-b --markdown

Output: the table on stdout, and ``benchmarks/results/seed_spread.csv``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent
SCORECARD = Path("results/report/reproduction.csv")


def seed_spread(runs: dict[str, Path]) -> pd.DataFrame:
    """Headline rows (in the first run's order) with ``Paper``, ``<run>`` and ``<run> / paper``
    per run, and ``spread`` (max over min of the ratios; NaN when a ratio is not positive).
    Every run must hold the same headlines with the same paper values."""
    if len(runs) < 2:
        raise ValueError(f"give at least two runs, got {list(runs)}")
    table = None
    for name, root in runs.items():
        path = Path(root) / SCORECARD
        if not path.is_file():
            raise FileNotFoundError(f"run {name!r}: no scorecard at {path} (run `snakemake all` there first)")
        card = pd.read_csv(path).set_index("Headline")
        part = card[["Paper"]].assign(**{name: card["trained"], f"{name} / paper": card["trained / paper"]})
        if table is None:
            table = part
            continue
        if set(part.index) != set(table.index) or not part["Paper"].reindex(table.index).equals(table["Paper"]):
            raise ValueError(f"run {name!r}: its scorecard holds other headlines or paper values than the first run's")
        table = table.join(part.drop(columns="Paper"))
    ratios = table[[f"{name} / paper" for name in runs]]
    spread = ratios.max(axis=1) / ratios.min(axis=1)
    table["spread"] = spread.where(ratios.min(axis=1) > 0)
    return table


def main(argv: list[str] | None = None) -> pd.DataFrame:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="NAME=DIR", help="a run's checkout, named")
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = parser.parse_args(argv)
    runs = {}
    for item in args.runs:
        name, sep, root = item.partition("=")
        if not sep or not name or not root:
            parser.error(f"{item!r} is not NAME=DIR")
        runs[name] = Path(root)
    table = seed_spread(runs)
    out = ROOT / "results" / "seed_spread.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out)
    print(table.to_markdown(floatfmt=".3g") if args.markdown else table.to_string(float_format="%.3g"))
    return table


if __name__ == "__main__":
    main()
