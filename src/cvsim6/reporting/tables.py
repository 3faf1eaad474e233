"""The paper's model tables (Table 1: inputs, Table 2: outputs), built from the registry.

Every name, unit, default and noise level comes from :mod:`cvsim6.registry`;
nothing is retyped here. Written by :func:`cvsim6.table_files.write_table` (re-exported here).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from operator import attrgetter
from pathlib import Path
from typing import Any

import pandas as pd

from cvsim6 import registry
from cvsim6.table_files import format_number, to_markdown, write_table

__all__ = [
    "format_number",
    "to_markdown",
    "write_table",
    "input_parameter_table",
    "output_parameter_table",
    "write_input_table",
    "write_output_table",
]


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
