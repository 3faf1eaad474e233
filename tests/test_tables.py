"""The model tables (cvsim6.reporting.tables) against the registry and the paper."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cvsim6.data import priors
from cvsim6 import registry
from cvsim6.reporting.tables import (
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


# The paper's Table 2, typed from the paper: unit and noise standard deviation of each output.
PAPER_TABLE_2 = [
    ("Hr", "bpm", 3.0), ("P_a_sys", "mmHg", 1.5), ("P_a_dia", "mmHg", 1.5), ("P_r_sys", "mmHg", 1.0),
    ("P_r_dia", "mmHg", 1.0), ("P_pa_sys", "mmHg", 1.0), ("P_pa_dia", "mmHg", 1.0), ("P_r_edp", "mmHg", 1.0),
    ("P_w", "mmHg", 1.0), ("P_cvp", "mmHg", 0.5), ("V_l_sys", "mL", 10.0), ("V_l_dia", "mL", 20.0),
    ("LVEF", "-", 0.02), ("CO", "L/min", 0.2), ("SVR", "dyn·s/cm^5", 50.0), ("PVR", "dyn·s/cm^5", 5.0),
]


def test_output_table_matches_the_papers_table_2():
    df = output_parameter_table()
    assert list(df.columns) == ["Num.", "Name", "Description", "Calculation", "Unit", "Noise std"]
    assert list(zip(df["Name"], df["Unit"], df["Noise std"])) == PAPER_TABLE_2


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
    np.testing.assert_array_equal(back["Noise std"].to_numpy(), [std for _, _, std in PAPER_TABLE_2])
    rows = [line for line in md.read_text(encoding="utf-8").splitlines() if line.startswith("|")]
    assert len(rows) == 2 + 16


# The paper's priors, from its text: section 3.3 (compliances +-50%, the rest +-30%) and
# section 3.4 (Hr -20%/+60%, compliances and resistances -80%/+60%, the rest +-30%).
@pytest.mark.parametrize("study, rules", [
    ("structural", {"compliance": (0.5, 1.5), "other": (0.7, 1.3)}),
    ("ehr", {"Hr": (0.8, 1.6), "compliance": (0.2, 1.6), "resistance": (0.2, 1.6), "other": (0.7, 1.3)}),
])
def test_prior_bounds_are_the_papers(study, rules):
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS[study])
    for i, p in enumerate(registry.PARAMETERS):
        m0, m1 = rules.get(p.name, rules.get(p.kind, rules["other"]))
        expected = sorted((m0 * p.default, m1 * p.default))  # P_th < 0: the interval flips
        assert (lo[i], hi[i]) == pytest.approx(expected), p.name
    assert (lo < hi).all()
