"""Sobol indices (cvsim6.studies.sensitivity): a function with known indices, the design's nested
subsets, the model's exact cases, the tables and the three-verdict table."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cvsim6.data import priors
from cvsim6.model import solver
from cvsim6.registry import OUTPUT_INDEX, PARAMETER_NAMES
from cvsim6.studies import sensitivity as se

# Ishigami function, a = 7, b = 0.1, on [-pi, pi]^3 (Ishigami & Homma 1990; Sobol' & Levitan 1999)
A, B = 7.0, 0.1
_V = A**2 / 8 + B * np.pi**4 / 5 + B**2 * np.pi**8 / 18 + 0.5
_V1 = 0.5 * (1 + B * np.pi**4 / 5) ** 2
_V2 = A**2 / 8
_V13 = B**2 * np.pi**8 * (1 / 18 - 1 / 50)
ISHIGAMI_S1 = np.array([_V1 / _V, _V2 / _V, 0.0])
ISHIGAMI_ST = np.array([(_V1 + _V13) / _V, _V2 / _V, _V13 / _V])


def ishigami(x: np.ndarray) -> np.ndarray:
    return np.sin(x[:, 0]) + A * np.sin(x[:, 1]) ** 2 + B * x[:, 2] ** 4 * np.sin(x[:, 0])


def test_ishigami_indices_lie_within_their_confidence_intervals():
    # the analytic values, to the digits usually quoted
    np.testing.assert_allclose(ISHIGAMI_S1, [0.3139, 0.4424, 0.0], atol=1e-4)
    np.testing.assert_allclose(ISHIGAMI_ST, [0.5576, 0.4424, 0.2437], atol=1e-4)
    prob = se.problem(np.full(3, -np.pi), np.full(3, np.pi), names=["x1", "x2", "x3"])
    X = se.design(prob, 4096, seed=3)
    df = se.indices(prob, ishigami(X)[:, None], 4096, seed=3, num_resamples=200)
    assert list(df["parameter"]) == ["x1", "x2", "x3"] and (df["n_base"] == 4096).all()
    for key, exact in (("S1", ISHIGAMI_S1), ("ST", ISHIGAMI_ST)):
        err = np.abs(df[key].to_numpy() - exact)
        conf = df[f"{key}_conf"].to_numpy()
        assert (err <= conf).all(), (key, err, conf)
        assert (conf < 0.05).all()  # and the intervals are tight enough to mean something


def test_design_is_seeded_and_nested():
    prob = se.problem(np.zeros(4), np.ones(4), names=["a", "b", "c", "d"])
    small, full = se.design(prob, 64, seed=5), se.design(prob, 256, seed=5)
    assert small.shape == (64 * 6, 4) and full.shape == (256 * 6, 4)
    # the convergence check's subsets are the first base points of the one design
    np.testing.assert_array_equal(small, full[: len(small)])
    np.testing.assert_array_equal(full, se.design(prob, 256, seed=5))
    assert not np.array_equal(full, se.design(prob, 256, seed=6))


@pytest.mark.parametrize("n", [0, 15, 100, 1000])
def test_n_base_must_be_a_power_of_two(n):
    with pytest.raises(ValueError, match=f"n_base = {n} must be a power of 2"):
        se.check_n_base(n)


def test_flagged_base_points_are_left_out_whole():
    prob = se.problem(np.full(3, -np.pi), np.full(3, np.pi), names=["x1", "x2", "x3"])
    X = se.design(prob, 256, seed=1)
    y = ishigami(X)
    y[7] = np.nan  # row 7 belongs to base point 1 (rows 5..9)
    df = se.indices(prob, y[:, None], 256, seed=1)
    assert (df["n_base"] == 255).all() and df[["S1", "ST"]].notna().all().all()


@pytest.fixture(scope="module")
def model_indices() -> pd.DataFrame:
    """Indices of all 16 outputs under the structural prior, 64 base points (1,600 sets, coarse steps)."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["structural"])
    prob = se.problem(lo, hi)
    X = se.design(prob, 64, seed=2)
    Y, status = solver.simulate_batch(X, steps_per_cycle=100)
    assert (status == 0).all()
    return se.indices(prob, Y, 64, seed=2)


def _output(df: pd.DataFrame, name: str) -> pd.DataFrame:
    return df[df["output"] == OUTPUT_INDEX[name]].set_index("parameter")


def test_hr_output_is_the_hr_parameter(model_indices):
    hr = _output(model_indices, "Hr")
    # estimates of 1 up to Monte Carlo error (64 base points), inside their intervals
    for key in ("S1", "ST"):
        assert abs(hr.at["Hr", key] - 1) <= hr.at["Hr", f"{key}_conf"] < 0.5
    others = hr.drop(index="Hr")
    assert (others[["S1", "ST", "S1_conf", "ST_conf"]].abs() < 1e-12).all().all()


def test_svr_depends_on_r_a_alone(model_indices):
    svr = _output(model_indices, "SVR")
    for key in ("S1", "ST"):
        assert abs(svr.at["R_a", key] - 1) <= svr.at["R_a", f"{key}_conf"] < 0.5
    assert (svr.drop(index="R_a")[["S1", "ST"]].abs() < 1e-9).all().all()
    # and an output that depends on many: cardiac output's total indices add up to at least 1
    co = _output(model_indices, "CO")
    assert co["ST"].sum() > 0.95 and (co["ST"] > 0.01).sum() >= 4


def test_sobol_steps_write_the_tables(tmp_path):
    sim = {"steps_per_cycle": 100, "n_cycles": 12, "window_cycles": 3}
    paths = []
    for name in ("structural", "ehr"):
        p = tmp_path / f"sobol_{name}.csv"
        se.sobol_prior(str(p), name, priors.PAPER_PRIORS[name], sim, n_base=16, bootstrap=10, conf_level=0.95, seed=0)
        paths.append(str(p))
    out = {k: str(tmp_path / f"{k}") for k in ("t.csv", "t.md", "c.csv", "c.md")}
    se.sobol_tables(paths, out["t.csv"], out["t.md"], out["c.csv"], out["c.md"])
    table = pd.read_csv(out["t.csv"])
    assert list(table.columns) == se.COLUMNS + ["n_base"]
    assert len(table) == 2 * 16 * 23 and set(table["prior"]) == {"structural", "ehr"}
    assert (table["n_base"] == 16).all()
    conv = pd.read_csv(out["c.csv"])
    assert sorted(conv["design_base"].unique()) == [4, 8, 16] and len(conv) == 6
    # the full design against itself: no change
    assert (conv.loc[conv["design_base"] == 16, ["max abs dS1 vs full", "max abs dST vs full"]] == 0).all().all()
    md = open(out["t.md"]).read()
    assert "| structural | Hr | Hr " in md and "| ehr | SVR | R_a " in md


def test_verdict_table_agreement_and_reasons():
    names = list(PARAMETER_NAMES)
    sobol = pd.DataFrame({"prior": "structural", "output": "CO", "parameter": names,
                          "ST": [0.5] * 3 + [0.001] * 20})
    local = pd.DataFrame({"Parameter": names, "null-space share (mean)": [0.0, 0.2, 0.2] + [0.2] * 20,
                          "manifold spread / prior width (95%)": [0.1, 0.9, 0.1] + [0.9] * 19 + [0.1]})
    t = se.verdict_table(sobol, local, "structural", influence_threshold=0.01, nonidentifiable_share=0.01,
                         spread_threshold=0.5).set_index("Parameter")
    assert t.loc["Hr", ["Sobol", "Jacobian", "inVAErt", "agree"]].tolist() == ["influential", "identifiable",
                                                                               "pinned", "yes"]
    assert t.loc["P_th", "agree"] == "no" and "compensated" in t.loc["P_th", "why not"]
    assert t.loc["r_sys", "agree"] == "no" and "barely moves" in t.loc["r_sys", "why not"]
    assert t.loc["C_l_dia", "agree"] == "yes" and t.loc["C_l_dia", "why not"] == ""
    assert t.loc["V0_pv", "inVAErt"] == "pinned" and "under-represents" in t.loc["V0_pv", "why not"]
    with pytest.raises(ValueError, match="no Sobol indices for prior 'ehr'"):
        se.verdict_table(sobol, local, "ehr", 0.01, 0.01, 0.5)
