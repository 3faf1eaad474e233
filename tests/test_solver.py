"""The batch solver against known values, invariants and the Radau reference."""
import numpy as np
import pandas as pd
import pytest

from cvsim6.model import equations as model
from cvsim6 import registry
from cvsim6.model import solver
from cvsim6.model.solver import STATUS_REASONS

NAMES = registry.OUTPUT_NAMES
I = registry.PARAMETER_INDEX
#: Agreement required of the batch path: 0.1% relative, or these absolute (units of each output).
ABS_TOL = np.array([0, .05, .05, .05, .05, .05, .05, .05, .05, .05, .1, .1, 5e-4, 5e-3, 1e-9, 1e-9])
#: Facts page, tightly converged implicit solve at the default parameters (outputs 2..16).
FACTS = {
    "P_a_sys": 109.450, "P_a_dia": 74.803, "P_r_sys": 22.181, "P_r_dia": -2.151,
    "P_pa_sys": 21.696, "P_pa_dia": 10.327, "P_r_edp": 0.901, "P_w": 8.913, "P_cvp": 6.814,
    "V_l_sys": 60.032, "V_l_dia": 131.768, "LVEF": 0.5444, "CO": 5.166, "SVR": 1333.3, "PVR": 106.6,
}


#: Radau's tolerance where the batch path is checked against it: errors of about 1e-7 of an output
#: (benchmarks/results/simulator_accuracy.json), 10,000 times below ``within``'s 1e-3, at 40% of
#: the CPU time of the solver's default 1e-10.
REFERENCE_RTOL = 1e-8


def within(a, b, abs_tol=ABS_TOL, rel=1e-3):
    a, b = np.asarray(a), np.asarray(b)
    return (np.abs(a - b) <= rel * np.abs(b)) | (np.abs(a - b) <= abs_tol)


@pytest.fixture(scope="module")
def default_batch(default_params):
    out, st = solver.simulate_batch(default_params)
    assert st[0] == 0
    return out[0]


@pytest.fixture(scope="module")
def default_reference(default_params):
    out, st = solver.simulate_reference(default_params, rtol=REFERENCE_RTOL, atol=REFERENCE_RTOL)
    assert st[0] == 0
    return out[0]


@pytest.mark.slow
@pytest.mark.parametrize("path", ["batch", "reference"])
def test_default_reproduces_facts_page(path, default_batch, default_reference):
    out = default_batch if path == "batch" else default_reference
    for name, ref in FACTS.items():
        j = registry.OUTPUT_INDEX[name]
        # the facts page rounds to the digits it prints
        tol = max(ABS_TOL[j], 1e-3 * abs(ref), 0.5 * 10.0 ** (-len(str(ref).split(".")[1])))
        assert abs(out[j] - ref) <= tol, (name, out[j], ref)
    assert out[0] == 72.0


def test_svr_is_arterial_resistance_in_clinical_units(structural_sets):
    """SVR = (mean P_a - mean P_v)/CO = R_a * 1000/60 * 80 exactly (no valve on Q_a)."""
    out, st = solver.simulate_batch(structural_sets[:16])
    assert (st == 0).all()
    np.testing.assert_allclose(out[:, NAMES.index("SVR")], structural_sets[:16, I["R_a"]] * 1000 / 60 * 80, rtol=1e-10)
    # LVEF is computed from the two volumes
    lv = (out[:, 11] - out[:, 10]) / out[:, 11]
    np.testing.assert_allclose(out[:, NAMES.index("LVEF")], lv, rtol=1e-14)


def test_total_volume_is_conserved_along_trajectory(ehr_sets):
    for p in (registry.default_parameters(), ehr_sets[3]):
        traj, out, st = solver.simulate_trajectory(p)
        assert st == 0
        vt = traj.V.sum(axis=1)
        assert np.abs(vt - registry.V_TOTAL_ML).max() < 1e-9 * registry.V_TOTAL_ML
        # pressures from volumes agree with the volume law of the model
        np.testing.assert_allclose(model.volumes(traj.t, traj.P, p), traj.V, rtol=1e-12, atol=1e-9)
        # valves follow the pressures: an open valve never carries backward flow
        for name, k in registry.VALVES.items():
            q = traj.Q[:, k]
            assert (q >= -1e-6 * np.abs(q).max()).all(), name
        # the trajectory's own extrema bound the reported outputs
        T = 60 / p[0]
        win = traj.t >= 9 * T - 1e-12
        assert out[1] >= traj.P[win, 1].max() - 1e-12
        assert out[2] <= traj.P[win, 1].min() + 1e-12
        assert traj.t[-1] == pytest.approx(12 * T)


@pytest.mark.slow
def test_reference_conserves_total_volume(default_params):
    sol = solver.reference_solution(default_params)
    t = np.linspace(0, sol.t_end, 3001)
    vt = model.total_volume(t, sol.pressures(t), default_params)
    assert np.abs(vt - registry.V_TOTAL_ML).max() < 1e-5


@pytest.mark.slow
def test_batch_matches_reference_on_both_priors(structural_sets, ehr_sets):
    """Random sets from the structural and the wide EHR prior (the stiff case)."""
    P = np.vstack([structural_sets[20:22], ehr_sets[20:23]])
    ref, rs = solver.simulate_reference(P, rtol=REFERENCE_RTOL, atol=REFERENCE_RTOL)
    out, st = solver.simulate_batch(P)
    assert (rs == 0).all() and (st == 0).all()
    ok = within(out, ref)
    assert ok.all(), [(r, NAMES[j], out[r, j], ref[r, j]) for r, j in np.argwhere(~ok)]


def test_rows_are_bit_identical_whatever_the_batch(ehr_sets):
    P = ehr_sets[:40]
    full, _ = solver.simulate_batch(P)
    for chunk in (1, 7):
        parts = [solver.simulate_batch(P[i:i + chunk])[0] for i in range(0, len(P), chunk)]
        assert np.array_equal(np.vstack(parts), full, equal_nan=True)
    alone, _ = solver.simulate_batch(P[5:6])
    assert np.array_equal(alone[0], full[5])


def test_flagged_row_leaves_other_rows_intact(structural_sets):
    P = structural_sets[:5].copy()
    # unstressed volumes above the total blood volume: negative compartment volumes
    P[2, I["V0_v"]] = 6000.0
    out, st = solver.simulate_batch(P)
    assert st[2] != 0 and STATUS_REASONS[int(st[2])] != "ok"
    good = np.delete(np.arange(5), 2)
    assert (st[good] == 0).all()
    alone, _ = solver.simulate_batch(P[good])
    assert np.array_equal(out[good], alone)
    df = solver.simulate(P)
    assert list(df.columns) == list(NAMES) + ["status"]
    assert df.loc[2, "status"] == STATUS_REASONS[int(st[2])]
    assert (df.drop(index=2)["status"] == "ok").all()


def test_out_of_domain_rows_flagged_on_request(structural_sets):
    """invalid="flag": out-of-domain rows get status 7 and no outputs; the others are the
    same bits as simulating them alone; outside_domain agrees with validate_parameters."""
    P = structural_sets[:6].copy()
    P[1, I["C_v"]] = -41.6
    P[3, I["r_sys"]] = 0.7
    P[4, I["R_a"]] = np.inf
    with pytest.raises(model.ParameterError, match="C_v = -41.6"):
        solver.simulate_batch(P)
    out, st = solver.simulate_batch(P, invalid="flag")
    bad = np.array([False, True, False, True, True, False])
    assert np.array_equal(model.outside_domain(P), bad)
    for r in range(len(P)):
        raises = False
        try:
            model.validate_parameters(P[r:r + 1])
        except model.ParameterError:
            raises = True
        assert raises == bad[r]
    assert (st[bad] == 7).all() and np.isnan(out[bad]).all()
    alone, st_alone = solver.simulate_batch(P[~bad])
    assert np.array_equal(out[~bad], alone) and np.array_equal(st[~bad], st_alone)
    with pytest.raises(ValueError, match="'skip'"):
        solver.simulate_batch(P, invalid="skip")


def test_bad_input_raises_naming_row_and_parameter(default_params):
    P = np.repeat(default_params[None], 3, axis=0)
    P[1, I["C_pv"]] = -0.5
    with pytest.raises(model.ParameterError, match=r"row 1: parameter C_pv = -0.5"):
        solver.simulate_batch(P)
    with pytest.raises(model.ParameterError, match=r"row 1: parameter C_pv"):
        solver.simulate(pd.DataFrame(P, columns=registry.PARAMETER_NAMES), method="reference")
    with pytest.raises(ValueError, match="unknown method"):
        solver.simulate(default_params, method="euler")


def test_trajectory_frame_has_every_signal(default_params):
    traj, _, _ = solver.simulate_trajectory(default_params, steps_per_cycle=200, n_cycles=4, window_cycles=1)
    df = traj.to_frame()
    for col in ["t", "P_l", "P_pv", "V_l", "Q_l_out", "Q_l_in", "C_l", "C_r",
                "valve_aortic", "valve_mitral", "valve_tricuspid", "valve_pulmonary"]:
        assert col in df
    assert df["t"].is_monotonic_increasing
    # the aortic valve opens and closes once per cycle
    opens = np.count_nonzero(np.diff(df["valve_aortic"].to_numpy()) == 1)
    assert opens == 4


@pytest.mark.slow
def test_valve_at_equilibrium_is_not_a_failure(tmp_path):
    """Rows of the default EHR data set where a valve at pressure equilibrium toggles
    within a step (once flagged as chatter) are accurate and not flagged."""
    from cvsim6.data import datasets
    from cvsim6.data import priors as pr

    prior = {"default": [0.7, 1.3], "kinds": {"compliance": [0.2, 1.6], "resistance": [0.2, 1.6]},
             "parameters": {"Hr": [0.8, 1.6]}}
    lo, hi = pr.prior_bounds(prior)
    rng = np.random.default_rng(datasets.study_seed(2024, "ehr"))
    P = pr.sample_uniform(lo, hi, 54000, rng)[[12003]]
    out, st = solver.simulate_batch(P)
    assert st[0] == 0
    ref, rs = solver.simulate_reference(P, rtol=REFERENCE_RTOL, atol=REFERENCE_RTOL)
    assert rs[0] == 0 and within(out, ref).all()


def test_unphysical_rows_are_simulated_and_flagged(default_params):
    """Parameters the equations accept but no circulation has (negative unstressed volume, a
    ventricle no stiffer in systole) get status 8 and keep their outputs; the others are untouched."""
    P = np.repeat(default_params[None], 4, axis=0)
    P[1, I["V0_v"]] = -100.0
    P[2, I["C_l_sys"]] = 20.0  # above C_l_dia = 10
    P[3, I["V0_l"]] = 0.0  # zero is a volume, not an unphysical one
    assert list(solver.unphysical(P)) == [False, True, True, False]
    out, st = solver.simulate_batch(P)
    assert list(st) == [0, 8, 8, 0]
    assert np.isfinite(out).all()
    alone, _ = solver.simulate_batch(P[[0, 3]])
    assert np.array_equal(out[[0, 3]], alone)
    # 2600 mL more stressed volume: a fuller, higher-pressure circulation; a weak left ventricle: low LVEF
    assert out[1, NAMES.index("P_a_sys")] > out[0, NAMES.index("P_a_sys")] + 100
    assert out[2, NAMES.index("LVEF")] < 0.2
    df = solver.simulate(P[:2])
    assert list(df["status"]) == ["ok", STATUS_REASONS[8]]


def test_reference_path_flags_unphysical_rows(default_params):
    P = np.repeat(default_params[None], 2, axis=0)
    P[1, I["V0_pa"]] = -5.0
    out, st = solver.simulate_reference(P, n_cycles=3, window_cycles=1, rtol=1e-6, atol=1e-6)
    assert list(st) == [0, 8] and np.isfinite(out).all()


def test_reference_failures_are_numerical_only(default_params, monkeypatch):
    """A numerical failure flags its row (status 6); a programming error propagates."""
    P = np.repeat(default_params[None], 2, axis=0)

    def fails(p, **kw):
        raise solver.IntegrationError("Radau failed at t = 0.1 s: step size too small")

    monkeypatch.setattr(solver, "reference_solution", fails)
    out, st = solver.simulate_reference(P)
    assert list(st) == [6, 6] and np.isnan(out).all()
    monkeypatch.setattr(solver, "reference_solution",
                        lambda p, **kw: (_ for _ in ()).throw(np.linalg.LinAlgError("singular matrix")))
    assert list(solver.simulate_reference(P)[1]) == [6, 6]

    def bug(p, **kw):
        raise TypeError("unsupported operand type(s)")

    monkeypatch.setattr(solver, "reference_solution", bug)
    with pytest.raises(TypeError, match="unsupported operand"):
        solver.simulate_reference(P)


def test_batch_kernel_bug_propagates(default_params, monkeypatch):
    def bug(*args):
        raise TypeError("kernel called with the wrong arguments")

    monkeypatch.setattr(solver._kernel, "batch", bug)
    with pytest.raises(TypeError, match="wrong arguments"):
        solver.simulate_batch(default_params)


def test_simulate_names_text_and_blank_cells(default_params):
    df = pd.DataFrame([default_params] * 3, columns=registry.PARAMETER_NAMES).astype(object)
    assert solver.first_invalid_row(df) is None
    df.loc[2, "R_pv"] = None
    df.loc[1, "C_a"] = "abc"
    assert solver.first_invalid_row(df) == (1, "C_a", "'abc' is not a number")
    with pytest.raises(model.ParameterError, match=r"^row 1: parameter C_a: 'abc' is not a number$"):
        solver.simulate(df)
    df.loc[1, "C_a"] = 1.6
    assert solver.first_invalid_row(df) == (2, "R_pv", "blank (a number is required)")
    df.loc[2, "R_pv"] = 0.08
    df.loc[0, "C_v"] = -3
    assert solver.first_invalid_row(df) == (0, "C_v", "-3.0 mL/mmHg must be > 0")
    with pytest.raises(ValueError, match=r"steps_per_cycle = 19 is too small \(need >= 20\)"):
        solver.simulate(default_params, steps_per_cycle=solver.MIN_STEPS_PER_CYCLE - 1)


def test_one_kernel_specialization_for_any_input_shape():
    """A one-row DataFrame (a read-only view), a (23,) vector and an N-row frame reach the
    compiled kernel as the same array type: one compilation serves them all (fresh process)."""
    code = ("import numpy as np, pandas as pd\n"
            "from cvsim6 import registry\n"
            "from cvsim6.model import _kernel, solver\n"
            "p = registry.default_parameters()\n"
            "df = pd.DataFrame([p, p * 1.01, p * 0.99], columns=registry.PARAMETER_NAMES)\n"
            "full = solver.simulate(df)\n"
            "one = solver.simulate(df.iloc[1:2])\n"
            "vec = solver.simulate_batch(p)[0]\n"
            "assert one.iloc[0].equals(full.iloc[1]), 'a row depends on its batch'\n"
            "assert np.array_equal(vec[0], full.iloc[0][list(registry.OUTPUT_NAMES)].to_numpy(float))\n"
            "print(len(_kernel.batch.signatures))\n")
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-1] == "1"
