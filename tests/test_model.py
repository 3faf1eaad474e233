"""The CVSim-6 equations: initial condition, right-hand side, Jacobian, input checks."""
import numpy as np
import pytest

from cvsim6.model import equations as model
from cvsim6 import registry
from cvsim6.model import solver

I = registry.PARAMETER_INDEX


@pytest.mark.parametrize("which", ["default", "structural", "ehr"])
def test_initial_condition_conserves_total_volume(which, default_params, structural_sets, ehr_sets):
    sets = {"default": default_params[None], "structural": structural_sets[:16], "ehr": ehr_sets[:16]}[which]
    for p in sets:
        P0 = model.initial_pressures(p)
        assert model.total_volume(0.0, P0, p) == pytest.approx(registry.V_TOTAL_ML, rel=1e-12)
        # ventricles start at their diastolic values: same stroke volume both sides
        M, rhs = model.initial_condition_system(p)
        x = np.linalg.solve(M, rhs)
        pth = p[I["P_th"]]
        sv_l = p[I["C_l_dia"]] * (x[0] - pth) - p[I["C_l_sys"]] * (x[1] - pth)
        sv_r = p[I["C_r_dia"]] * (x[2] - pth) - p[I["C_r_sys"]] * (x[3] - pth)
        assert sv_l == pytest.approx(sv_r, rel=1e-10)
        assert sv_l > 0


def test_activation_is_continuous_with_continuous_slope():
    T, Ts = 60 / 72, 0.3 * 60 / 72
    for t0 in (Ts, 1.5 * Ts, T):
        a, da = model.activation(np.array([t0 - 1e-9, t0 + 1e-9]), T, Ts)
        assert abs(a[0] - a[1]) < 1e-7
        assert abs(da[0] - da[1]) < 1e-5
    a, _ = model.activation(np.array([0.0, Ts, 1.5 * Ts, 0.9 * T]), T, Ts)
    np.testing.assert_allclose(a, [0.0, 1.0, 0.0, 0.0], atol=1e-15)


def test_jacobian_matches_finite_differences(default_params, ehr_sets):
    rng = np.random.default_rng(0)
    for p in (default_params, ehr_sets[0], ehr_sets[1]):
        T, _ = model.cycle_times(p)
        for t in rng.uniform(0, T, 5):
            P = model.initial_pressures(p) + rng.normal(0, 3, 6)
            states = model.valve_states(P)
            A, _ = model.linear_system(t, P, p, states)
            eps = 1e-6
            fd = np.empty((6, 6))
            for j in range(6):
                e = np.zeros(6)
                e[j] = eps
                fd[:, j] = (model.rhs_pressure(t, P + e, p, states) - model.rhs_pressure(t, P - e, p, states)) / (2 * eps)
            np.testing.assert_allclose(A, fd, rtol=1e-6, atol=1e-6 * np.abs(A).max())


def test_volume_rhs_is_mass_conserving(default_params):
    """sum_i dV_i/dt = 0: d/dt sum V = sum C_i dP_i/dt + dC_i (P_i - off_i) = 0."""
    p = default_params
    rng = np.random.default_rng(1)
    for t in rng.uniform(0, 60 / 72, 7):
        P = model.initial_pressures(p) + rng.normal(0, 5, 6)
        dP = model.rhs_pressure(t, P, p)
        C, dC = model.compliances(t, p)
        dV = C * dP + dC * (P - model.pressure_offsets(p))
        assert abs(dV.sum()) < 1e-9 * np.abs(dV).max()


@pytest.mark.parametrize(
    "name, value, match",
    [
        ("C_a", 0.0, r"row 2: parameter C_a = 0.0 mL/mmHg must be > 0"),
        ("R_pv", -1.0, r"row 2: parameter R_pv = -1.0 .* must be > 0"),
        ("Hr", 0.0, r"row 2: parameter Hr = 0.0 bpm must be > 0"),
        ("V0_v", np.nan, r"row 2: parameter V0_v = nan is not finite"),
        ("r_sys", 0.7, r"row 2: parameter r_sys = 0.7 must lie in \(0, 2/3\)"),
        ("r_sys", 0.0, r"row 2: parameter r_sys = 0.0 must lie in \(0, 2/3\)"),
    ],
)
def test_bad_parameters_name_parameter_and_row(default_params, name, value, match):
    P = np.repeat(default_params[None], 4, axis=0)
    P[2, I[name]] = value
    with pytest.raises(model.ParameterError, match=match):
        model.validate_parameters(P)


def test_parameter_frame_needs_every_name(default_params):
    import pandas as pd

    df = pd.DataFrame([default_params], columns=registry.PARAMETER_NAMES).drop(columns=["C_v"])
    with pytest.raises(model.ParameterError, match="C_v"):
        model.as_parameter_array(df)


@pytest.mark.parametrize("which", ["default", "ehr"])
def test_compiled_kernel_starts_from_the_models_initial_condition(which, default_params, ehr_sets):
    """The numba kernel solves the appendix-A system itself; its first node must be the
    pressures cvsim6.model.equations.initial_pressures gives (and the volumes they imply)."""
    for p in {"default": default_params[None], "ehr": ehr_sets[:4]}[which]:
        traj, _, status = solver.simulate_trajectory(p, n_cycles=4, window_cycles=1)
        assert traj.t[0] == 0.0
        P0 = model.initial_pressures(p)
        np.testing.assert_allclose(traj.P[0], P0, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(traj.V[0], model.volumes(0.0, P0, p), rtol=1e-12)
        np.testing.assert_array_equal(traj.valves[0, [0, 2, 3, 5]], model.valve_states(P0)[[0, 2, 3, 5]])
