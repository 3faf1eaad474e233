"""Stiffness analysis (paper section 3.1): closed-form eigenvalues, the SR rule, RK4 drift."""
import numpy as np
import pytest

from cvsim6.model import equations as model
from cvsim6 import registry
from cvsim6.model import solver
from cvsim6.model import stiffness

I = registry.PARAMETER_INDEX


def _states(open_valves):
    s = np.ones(6, dtype=np.int64)
    for name, k in registry.VALVES.items():
        s[k] = int(name in open_valves)
    return s


def test_all_valves_closed_eigenvalues_in_closed_form(default_params):
    """All valves closed: the ventricles decouple (eigenvalue -dC/dt / C each) and the
    a-v and pa-pv pairs are RC circuits (0 and -(1/R)(1/C_j + 1/C_k))."""
    p = default_params
    T, Ts = model.cycle_times(p)
    for tc in (0.2 * Ts, 1.2 * Ts, 0.9 * T):  # contraction, relaxation, diastole (dC = 0)
        C, dC = model.compliances(np.array([tc]), p)
        A, _ = model.linear_system(tc, np.zeros(6), p, _states(()))
        lam, _ = stiffness.sorted_eigen(A)
        expected = [
            -dC[0, 0] / C[0, 0],
            -dC[0, 3] / C[0, 3],
            0.0,
            -(1 / p[I["R_a"]]) * (1 / p[I["C_a"]] + 1 / p[I["C_v"]]),
            0.0,
            -(1 / p[I["R_pv"]]) * (1 / p[I["C_pa"]] + 1 / p[I["C_pv"]]),
        ]
        np.testing.assert_allclose(np.sort(lam.real), np.sort(expected), rtol=1e-10, atol=1e-12)
        assert np.abs(lam.imag).max() == 0.0
    # the paper's SR-min instant: lambda_1 = -4.40 and lambda_4 = -0.64 are these RC pairs
    assert expected[5] == pytest.approx(-4.40, abs=5e-3)
    assert expected[3] == pytest.approx(-0.635, abs=1e-3)


def test_ejection_fast_modes_match_outflow_rc(default_params):
    """At peak activation (dC/dt = 0) with aortic and pulmonary valves open, the two
    fastest time scales are close to the outflow RC constants (paper: 0.0019, 0.0028 s)."""
    p = default_params
    _, Ts = model.cycle_times(p)
    A, _ = model.linear_system(Ts, np.zeros(6), p, _states(("aortic", "pulmonary")))
    lam, Q = stiffness.sorted_eigen(A)
    rc = stiffness.rc_constants(Ts, p)
    assert 1 / abs(lam[0].real) == pytest.approx(rc["RC_left"], rel=2e-3)
    assert 1 / abs(lam[1].real) == pytest.approx(rc["RC_right"], rel=2e-3)
    assert rc["RC_left"] == pytest.approx(0.0019, abs=5e-5)
    assert rc["RC_right"] == pytest.approx(0.0028, abs=5e-5)
    # the fast modes live on the left (P_l, P_a) and right (P_r, P_pa) outflow
    assert set(np.argsort(-np.abs(Q[:, 0]))[:2]) == {0, 1}
    assert set(np.argsort(-np.abs(Q[:, 1]))[:2]) == {3, 4}
    # two closed loops (l-a-v, r-pa-pv) each conserve volume: two zero eigenvalues at dC = 0
    assert np.abs(lam[4:].real).max() < 1e-10


def test_stiffness_ratio_rule():
    # zeros below the tolerance are skipped; tol is added to the smallest non-zero one
    lam = np.array([-520.95, -355.93, -3.75, -0.51, 6.25e-4, 2.91e-5])
    assert stiffness.stiffness_ratio(lam, 1e-10, 1e-14) == pytest.approx(520.95 / (2.91e-5 + 1e-14))
    lam = np.array([-4.40, -1.81, -1.77, -0.64, 2.22e-16, 3.47e-18])
    assert stiffness.stiffness_ratio(lam, 1e-10, 1e-14) == pytest.approx(4.40 / 0.64)
    # the sign does not matter, the tolerance does
    assert stiffness.stiffness_ratio(np.array([2.0, -1e-3]), 1e-10, 1e-3) == pytest.approx(1000.0)
    # with a tiny zero threshold a round-off "zero" makes SR explode
    assert stiffness.stiffness_ratio(np.array([-1.0, 1e-16]), 1e-20, 0.0) == pytest.approx(1e16)
    # vectorised over rows; an all-zero row gives NaN
    out = stiffness.stiffness_ratio(np.array([[-2.0, -1.0, 0.0], [0.0, 0.0, 0.0]]), 1e-10, 0.0)
    assert out[0] == pytest.approx(2.0) and np.isnan(out[1])


def test_rk4_volume_drift_shrinks_with_step(default_params):
    p = default_params
    drift = {}
    for h in (4e-3, 2e-2):
        t, P = stiffness.rk4(p, h, n_cycles=3)
        assert np.isfinite(P).all()
        drift[h] = np.abs(model.total_volume(t, P, p) - registry.V_TOTAL_ML).max()
    assert drift[4e-3] < 1.0
    assert drift[2e-2] > 5 * drift[4e-3]


def test_rk4_small_step_tracks_reference(default_params):
    p = default_params
    sol = solver.reference_solution(p, n_cycles=1, rtol=1e-8, atol=1e-8)
    t, P = stiffness.rk4(p, 2e-3, n_cycles=1)
    assert np.abs(P[:, 0] - sol.pressures(t)[:, 0]).max() < 0.5


def test_eigen_series_extremes_along_reference(default_params):
    """Short run: SR peaks at peak activation (aortic and pulmonary open) and is
    smallest with all valves closed; the eigenvalues there are real."""
    p = default_params
    T, Ts = model.cycle_times(p)
    sol = solver.reference_solution(p, n_cycles=3, rtol=1e-8, atol=1e-8)
    t = stiffness.analysis_times(p, 300, n_cycles=3, n_last=1)
    eig = stiffness.eigen_series(sol, t, 1e-10, 1e-14)
    assert list(eig.columns) == ["t", *stiffness.LAMBDA_COLUMNS, "max_abs_imag", "SR"]
    assert eig["max_abs_imag"].max() < 1e-8
    lam = eig[list(stiffness.LAMBDA_COLUMNS)].to_numpy()
    assert (np.abs(lam[:, :-1]) >= np.abs(lam[:, 1:])).all()  # sorted by |Re| descending
    rows = stiffness.extreme_rows(eig)
    t_max, t_min = t[rows["SR max"]], t[rows["SR min"]]
    assert abs(t_max % T - Ts) < 2 * T / 300
    assert (sol.states(t_max)[0][[0, 3]] == 1).all()
    assert (sol.states(t_min)[0][[0, 2, 3, 5]] == 0).all()
    assert eig["SR"].iloc[rows["SR max"]] > 1e5
    assert eig["SR"].iloc[rows["SR min"]] == pytest.approx(4.395 / 0.635, rel=1e-2)


def test_eigenvalue_figure_draws_each_eigenvalue_column(tmp_path, monkeypatch):
    """Figure 2 from a small eigenvalue CSV: one series per lambda column in both panels, the
    bottom one |Re lambda| floored at 1e-19 (an exact zero sits at the bottom edge)."""
    import pandas as pd
    from matplotlib.image import imread

    from cvsim6.reporting import stiffness_figures

    t = np.linspace(0.0, 1.0, 11)
    lam = -np.outer(np.linspace(1.0, 2.0, 11), [500.0, 300.0, 4.0, 0.6, 1e-3, 0.0])
    df = pd.DataFrame(lam, columns=list(stiffness.LAMBDA_COLUMNS))
    df.insert(0, "t", t)
    df["max_abs_imag"], df["SR"] = 0.0, 1e5
    df.to_csv(tmp_path / "eig.csv", index=False)
    kept = {}
    save = stiffness_figures._save
    monkeypatch.setattr(stiffness_figures, "_save", lambda fig, png, pdf: (kept.setdefault("fig", fig),
                                                                           save(fig, png, pdf)))
    stiffness_figures.eigenvalue_figure(str(tmp_path / "eig.csv"), str(tmp_path / "e.png"), str(tmp_path / "e.pdf"),
                                        zero_eigenvalue_tol=1e-10)
    top, bottom = kept["fig"].axes
    np.testing.assert_array_equal(np.array([ln.get_ydata() for ln in top.get_lines()[:6]]).T, lam)
    np.testing.assert_array_equal(bottom.get_lines()[5].get_ydata(), np.full(11, 1e-19))
    assert [ln.get_label() for ln in top.get_lines()[:6]] == [rf"$\lambda_{j}$" for j in range(1, 7)]
    assert imread(tmp_path / "e.png").shape[2] == 4 and (tmp_path / "e.pdf").stat().st_size > 5_000
