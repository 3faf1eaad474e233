"""The model tables (cvsim6.tables) against the registry and the paper."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cvsim6 import registry
from cvsim6.tables import (
    format_number,
    input_parameter_table,
    output_parameter_table,
    write_input_table,
    write_output_table,
)

# Values of the paper's Table 1 (CGS units), printed there to 3 significant digits.
PAPER_CGS = {
    "Hr": 72.0,
    "C_l_dia": 7.50e-3,
    "C_l_sys": 3.00e-4,
    "C_v": 7.50e-2,
    "C_pa": 3.23e-3,
    "C_pv": 6.30e-3,
    "R_l_in": 13.33,
    "R_a": 1333.22,
    "R_pv": 106.66,
    "V0_v": 2500.0,
}


def test_input_table_follows_registry():
    df = input_parameter_table()
    assert list(df.columns) == [
        "Num.", "Name", "Description", "Default (clinical)", "Unit (clinical)", "Default (CGS)", "Unit (CGS)",
    ]
    assert tuple(df["Name"]) == registry.PARAMETER_NAMES
    assert len(df) == 23
    assert list(df["Num."]) == list(range(1, 24))
    np.testing.assert_allclose(df["Default (clinical)"], registry.default_parameters())
    assert df.set_index("Name").loc["C_a", "Unit (CGS)"] == "mL/Barye"


@pytest.mark.parametrize("name,value", sorted(PAPER_CGS.items()))
def test_input_table_cgs_values_match_paper(name, value):
    cgs = input_parameter_table().set_index("Name")["Default (CGS)"]
    assert cgs[name] == pytest.approx(value, rel=2e-3)


def test_output_table_follows_registry():
    df = output_parameter_table()
    assert list(df.columns) == ["Num.", "Name", "Description", "Calculation", "Unit", "Noise std"]
    assert tuple(df["Name"]) == registry.OUTPUT_NAMES
    np.testing.assert_array_equal(df["Noise std"].to_numpy(), registry.noise_std())
    assert list(df["Unit"]) == [o.unit for o in registry.OUTPUTS]


@pytest.mark.parametrize(
    "x,text",
    [(72.0, "72.00"), (1 / 3, "0.33"), (1333.22, "1333.22"), (3e-4, "3.00e-04"), (0.075, "7.50e-02"),
     (-4.0, "-4.00"), (3, "3"), (0.0, "0.00"), (2.5e6, "2.50e+06"), ("mL", "mL")],
)
def test_format_number(x, text):
    assert format_number(x) == text


def test_written_input_table(tmp_path):
    csv, md = tmp_path / "t" / "in.csv", tmp_path / "t" / "in.md"
    write_input_table(str(csv), str(md))
    back = pd.read_csv(csv)
    pd.testing.assert_frame_equal(back, input_parameter_table(), check_dtype=False)
    rows = [line for line in md.read_text(encoding="utf-8").splitlines() if line.startswith("|")]
    assert rows[0].startswith("| Num. | Name | Description |")
    assert set(rows[1].replace("|", "")) == {"-"}
    data = rows[2:]
    assert len(data) == 23
    assert [r.split("|")[2].strip() for r in data] == list(registry.PARAMETER_NAMES)
    c_l_dia = next(r for r in data if "| C_l_dia |" in r)
    assert "| 7.50e-03 | mL/Barye |" in c_l_dia
    assert "| 1333.22 |" in next(r for r in data if "| R_a |" in r)


def test_written_output_table(tmp_path):
    csv, md = tmp_path / "out.csv", tmp_path / "out.md"
    write_output_table(csv, md)
    back = pd.read_csv(csv)
    np.testing.assert_array_equal(back["Noise std"].to_numpy(), registry.noise_std())
    rows = [line for line in md.read_text(encoding="utf-8").splitlines() if line.startswith("|")]
    assert len(rows) == 2 + 16
