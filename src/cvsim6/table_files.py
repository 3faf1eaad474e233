"""Tables as files: one DataFrame written twice, as CSV (full precision, for machines) and as
Markdown (rounded like the paper, for people). Shared by every stage that writes a table, so it
imports nothing of the package: an edit of a table's content reruns that table's rule only."""
from __future__ import annotations

import math
from numbers import Integral, Real
from pathlib import Path

import pandas as pd

__all__ = ["format_number", "to_markdown", "write_table"]


def format_number(x: object) -> str:
    """Format one table cell the way the paper does.

    Integers print as such; floats with 0.1 <= |x| < 1e5 get two decimals
    (``72.00``, ``0.33``, ``1333.22``); smaller or larger ones use scientific
    notation with three significant digits (``7.50e-02``, ``3.00e-04``), so no
    value loses more than its third digit. Anything else prints as ``str``.
    """
    if isinstance(x, bool) or not isinstance(x, Real):
        return str(x)
    if isinstance(x, Integral):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return ""
    if x == 0.0:
        return "0.00"
    if 0.1 <= abs(x) < 1e5:
        return f"{x:.2f}"
    return f"{x:.2e}"


def to_markdown(df: pd.DataFrame, caption: str | None = None) -> str:
    """A GitHub-flavoured Markdown table of ``df`` (index dropped), caption above it."""

    def cell(value: object) -> str:
        return format_number(value).replace("|", r"\|").replace("\n", " ")

    header = [str(c) for c in df.columns]
    rows = [[cell(v) for v in row] for row in df.itertuples(index=False, name=None)]
    lines = []
    if caption:
        lines += [f"**{caption}**", ""]
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join("---" for _ in header) + "|")
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_table(df: pd.DataFrame, csv: str | Path, md: str | Path, caption: str | None = None) -> None:
    """Write ``df`` as CSV (full precision, no index) and as a Markdown table."""
    for path in (csv, md):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(csv, index=False)
    Path(md).write_text(to_markdown(df, caption), encoding="utf-8")
