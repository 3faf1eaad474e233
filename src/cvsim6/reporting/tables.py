"""The paper's model tables (Table 1: inputs, Table 2: outputs), built from the registry.

Every name, unit, default and noise level comes from :mod:`cvsim6.registry`;
nothing is retyped here. Tables are written twice: as CSV (full precision,
for machines) and as Markdown (rounded like the paper, for people).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from numbers import Integral, Real
from operator import attrgetter
from pathlib import Path
from typing import Any

import pandas as pd

from cvsim6 import registry

__all__ = [
    "format_number",
    "to_markdown",
    "write_table",
    "input_parameter_table",
    "output_parameter_table",
    "write_input_table",
    "write_output_table",
]


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


def _registry_table(entries: Sequence, columns: Mapping[str, Callable[[Any], object]]) -> pd.DataFrame:
    """One row per registry entry (parameter or output): ``Num.`` (1-based), ``Name``,
    ``Description``, then one column per ``{header: value of an entry}`` of ``columns``."""
    columns = {"Name": attrgetter("name"), "Description": attrgetter("description"), **columns}
    return pd.DataFrame({"Num.": range(1, len(entries) + 1),
                         **{header: [value(e) for e in entries] for header, value in columns.items()}})


def input_parameter_table() -> pd.DataFrame:
    """Table 1 of the paper: the 23 inputs with defaults in clinical and CGS units."""
    return _registry_table(registry.PARAMETERS, {
        "Default (clinical)": attrgetter("default"),
        "Unit (clinical)": attrgetter("unit"),
        "Default (CGS)": lambda p: p.default * p.cgs_factor,
        "Unit (CGS)": attrgetter("cgs_unit"),
    })


def output_parameter_table() -> pd.DataFrame:
    """Table 2 of the paper: the 16 outputs, how they are computed, and their noise std."""
    return _registry_table(registry.OUTPUTS, {
        "Calculation": attrgetter("calculation"),
        "Unit": attrgetter("unit"),
        "Noise std": attrgetter("noise_std"),
    })


def write_input_table(csv: str | Path, md: str | Path) -> None:
    """Write Table 1 (model inputs) to ``csv`` and ``md``."""
    write_table(
        input_parameter_table(),
        csv,
        md,
        caption=f"CVSim-6 input parameters and defaults (1 mmHg = {registry.MMHG_TO_BARYE} Barye).",
    )


def write_output_table(csv: str | Path, md: str | Path) -> None:
    """Write Table 2 (model outputs and measurement-noise std) to ``csv`` and ``md``."""
    write_table(
        output_parameter_table(),
        csv,
        md,
        caption="CVSim-6 outputs and the standard deviation of their measurement noise.",
    )
