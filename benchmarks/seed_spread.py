"""The reproduction scorecard of several runs side by side: how much of the gap is the seed's.

Each run is one ``snakemake all`` of the same config with another master seed (``--config
seed=2025``), in a checkout of its own; this reads each run's
``results/report/reproduction.csv`` (the ``trained`` column) and writes one row per headline:
the paper's value, each run's value and its ratio to the paper, and the spread of the ratios
(largest over smallest, a ratio >= 1).

    .venv/bin/python benchmarks/seed_spread.py seed2024=<checkout> seed2025=<checkout> --markdown

Output: the table on stdout, and ``benchmarks/results/seed_spread.json``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

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
    import results_io

    results_io.add_note_argument(parser)
    args = parser.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/seed_spread.py", *argv])
    runs = {}
    for item in args.runs:
        name, sep, root = item.partition("=")
        if not sep or not name or not root:
            parser.error(f"{item!r} is not NAME=DIR")
        runs[name] = Path(root)
    table = seed_spread(runs)
    print(table.to_markdown(floatfmt=".3g") if args.markdown else table.to_string(float_format="%.3g"))
    formats = {c: ".3g" for c in table.columns}
    run.save("seed_spread", "Reproduction scorecard across master seeds",
             "The reproduction scorecard (results/report/reproduction.csv, the trained column) of several "
             "runs of the workflow that differ in the master seed only, side by side: each run's value and its "
             "ratio to the paper per headline, and the spread of the ratios (largest over smallest).",
             [results_io.table(table, "scorecards", "Per headline: the paper's value, each run's and its ratio "
                               "to the paper, and the spread of the ratios.", formats, index=True)],
             parameters={"runs": {name: results_io.portable(str(Path(root).resolve())) for name, root in runs.items()}},
             note=args.note)
    return table


if __name__ == "__main__":
    main()
