"""The CVSim-6 six-compartment lumped-parameter model (paper section 2.1, appendix A).

Units. Parameters are in clinical units (see :mod:`cvsim6.registry`); the equations
are solved in mmHg, mL and s. The ODE is homogeneous in the pressure unit (every
R·C product and every flow is invariant), so solving in mmHg gives exactly the
same trajectories as the CGS formulation of the paper; only the reported units differ.

Compartments are ordered ``l, a, v, r, pa, pv`` (:data:`cvsim6.registry.COMPARTMENTS`).
Flow ``k`` runs from compartment ``k`` to ``k+1`` (mod 6); flows 0, 2, 3, 5 pass
through the aortic, tricuspid, pulmonary and mitral valves (ideal diodes).

Pressure-volume law of each compartment: ``V_i = V0_i + C_i(t) (P_i - off_i)`` with
offsets ``off = (P_th, P_th/3, 0, P_th, P_th, P_th)`` (mmHg); only the ventricular
compliances ``C_l(t)``, ``C_r(t)`` vary in time (the activation functions of appendix A).
"""
from __future__ import annotations

import numpy as np

from cvsim6.registry import (
    N_PARAMETERS,
    PARAMETER_INDEX,
    PARAMETER_NAMES,
    PARAMETERS,
    V_TOTAL_ML,
)

_I = PARAMETER_INDEX
#: Valve mask over the six flows (1 = gated by an ideal valve).
VALVE_MASK = np.array([1, 0, 1, 1, 0, 1], dtype=np.int64)


class ParameterError(ValueError):
    """A parameter set the model cannot accept; the message names parameter and row."""


def as_parameter_array(params) -> np.ndarray:
    """Return ``params`` as a float64 array of shape (N, 23) in registry order.

    Accepts an (N, 23) or (23,) array, or a pandas DataFrame with the 23 parameter
    names as columns (extra columns are ignored; a missing one is an error). The result is
    C-contiguous and writeable whatever the input, so the compiled kernels see one array
    type (a read-only view, e.g. of a one-row DataFrame, would compile a second one).
    """
    try:
        import pandas as pd
    except ImportError:  # pragma: no cover - pandas is a dependency
        pd = None
    if pd is not None and isinstance(params, pd.DataFrame):
        missing = [n for n in PARAMETER_NAMES if n not in params.columns]
        if missing:
            raise ParameterError(f"missing parameter column(s): {', '.join(missing)}")
        arr = params.loc[:, list(PARAMETER_NAMES)].to_numpy(dtype=float)
    else:
        arr = np.asarray(params, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != N_PARAMETERS:
        raise ParameterError(f"expected parameters of shape (N, {N_PARAMETERS}), got {arr.shape}")
    return np.require(arr, dtype=np.float64, requirements=["C", "W"])


_POSITIVE = [i for i, p in enumerate(PARAMETERS) if p.kind in ("compliance", "resistance") or p.name == "Hr"]


def outside_domain(params: np.ndarray) -> np.ndarray:
    """Boolean mask (N,) of the rows :func:`validate_parameters` rejects: a value not
    finite, heart rate, a compliance or a resistance <= 0, or ``r_sys`` outside (0, 2/3)."""
    arr = np.atleast_2d(np.asarray(params, dtype=float))
    with np.errstate(invalid="ignore"):
        r = arr[:, _I["r_sys"]]
        return (~np.isfinite(arr).all(axis=1) | (arr[:, _POSITIVE] <= 0).any(axis=1)
                | (r <= 0) | (r >= 2.0 / 3.0))


def validate_parameters(params: np.ndarray) -> None:
    """Raise :class:`ParameterError` naming the first bad row (0-based) and its parameter.

    Checked: every value finite; heart rate, compliances and resistances > 0;
    ``r_sys`` in (0, 2/3) so that the activation (1.5 T_sys long) fits in one cycle.
    """
    arr = np.atleast_2d(np.asarray(params, dtype=float))
    bad = outside_domain(arr)
    if not bad.any():
        return
    row = int(np.argmax(bad))
    x = arr[row]
    for col in np.flatnonzero(~np.isfinite(x)):
        raise ParameterError(f"row {row}: parameter {PARAMETER_NAMES[col]} = {float(x[col])!r} is not finite")
    for col in _POSITIVE:
        if x[col] <= 0:
            p = PARAMETERS[col]
            raise ParameterError(f"row {row}: parameter {p.name} = {float(x[col])!r} {p.unit} must be > 0")
    raise ParameterError(f"row {row}: parameter r_sys = {float(x[_I['r_sys']])!r} must lie in (0, 2/3)")


def cycle_times(p: np.ndarray) -> tuple[float, float]:
    """Cardiac period ``T_tot = 60/Hr`` and systolic time ``T_sys = r_sys T_tot`` (s)."""
    T = 60.0 / p[_I["Hr"]]
    return T, p[_I["r_sys"]] * T


def activation(t, T: float, Ts: float):
    """Activation ``a(t)`` in [0, 1] and ``da/dt`` (1/s) of appendix A.

    Elastance is ``E(t) = E_dia + (E_sys - E_dia) a(t)``: ``a = (1 - cos(pi t/Ts))/2``
    on (0, Ts], ``(1 + cos(2 pi (t - Ts)/Ts))/2`` on (Ts, 1.5 Ts], 0 elsewhere (t mod T).
    """
    tc = np.mod(np.asarray(t, dtype=float), T)
    a = np.zeros_like(tc)
    da = np.zeros_like(tc)
    m1 = (tc > 0) & (tc <= Ts)
    m2 = (tc > Ts) & (tc <= 1.5 * Ts)
    a = np.where(m1, 0.5 * (1 - np.cos(np.pi * tc / Ts)), a)
    da = np.where(m1, 0.5 * np.pi / Ts * np.sin(np.pi * tc / Ts), da)
    a = np.where(m2, 0.5 * (1 + np.cos(2 * np.pi * (tc - Ts) / Ts)), a)
    da = np.where(m2, -np.pi / Ts * np.sin(2 * np.pi * (tc - Ts) / Ts), da)
    return a, da


def compliances(t, p: np.ndarray):
    """Compliances of the six compartments at time(s) ``t`` (mL/mmHg) and their rates.

    Returns ``C`` and ``dC/dt`` of shape ``t.shape + (6,)``.
    """
    T, Ts = cycle_times(p)
    a, da = activation(t, T, Ts)
    C = np.empty(np.shape(a) + (6,))
    dC = np.zeros_like(C)
    for k, (dia, sys) in ((0, ("C_l_dia", "C_l_sys")), (3, ("C_r_dia", "C_r_sys"))):
        Ed, Es = 1.0 / p[_I[dia]], 1.0 / p[_I[sys]]
        E = Ed + (Es - Ed) * a
        C[..., k] = 1.0 / E
        dC[..., k] = -(Es - Ed) * da / E**2
    for k, name in ((1, "C_a"), (2, "C_v"), (4, "C_pa"), (5, "C_pv")):
        C[..., k] = p[_I[name]]
    return C, dC


def pressure_offsets(p: np.ndarray) -> np.ndarray:
    """Offsets ``off_i`` of the pressure-volume laws (mmHg)."""
    pth = p[_I["P_th"]]
    return np.array([pth, pth / 3.0, 0.0, pth, pth, pth])


def unstressed_volumes(p: np.ndarray) -> np.ndarray:
    """Unstressed volumes ``V0`` of the six compartments (mL)."""
    return p[[_I[n] for n in ("V0_l", "V0_a", "V0_v", "V0_r", "V0_pa", "V0_pv")]].astype(float)


def conductances(p: np.ndarray) -> np.ndarray:
    """Conductances 1/R of the six flows (mL/(s·mmHg)), in flow order."""
    names = ("R_l_out", "R_a", "R_r_in", "R_r_out", "R_pv", "R_l_in")
    return 1.0 / p[[_I[n] for n in names]]


def initial_condition_system(p: np.ndarray, v_total: float = V_TOTAL_ML):
    """The 8x8 linear system of appendix A: returns ``(M, rhs)``.

    Unknowns ``[P_l_dia, P_l_sys, P_r_dia, P_r_sys, P_a, P_v, P_pa, P_pv]`` (mmHg):
    equal stroke volumes of both ventricles equal the volume each segment of the
    circuit passes in its phase of the cycle, and the stressed volumes add up to
    ``V_tot - V0_tot``.
    """
    g = lambda n: p[_I[n]]  # noqa: E731
    T, Ts = cycle_times(p)
    Td = T - Ts
    pth = g("P_th")
    Cld, Cls, Crd, Crs = g("C_l_dia"), g("C_l_sys"), g("C_r_dia"), g("C_r_sys")
    M = np.zeros((8, 8))
    rhs = np.zeros(8)
    # left stroke volume: SV_l = Cld (Pld - pth) - Cls (Pls - pth)
    sv_l = np.array([Cld, -Cls, 0, 0, 0, 0, 0, 0], dtype=float)
    sv_l_const = -Cld * pth + Cls * pth
    # 1: SV_l = SV_r
    M[0] = sv_l - np.array([0, 0, Crd, -Crs, 0, 0, 0, 0])
    rhs[0] = -(sv_l_const - (-Crd * pth + Crs * pth))
    # 2..7: SV_l = duration * (P_up - P_down) / R
    segments = [
        (Ts, "R_l_out", 1, 4),  # P_l_sys -> P_a
        (T, "R_a", 4, 5),  # P_a -> P_v
        (Td, "R_r_in", 5, 2),  # P_v -> P_r_dia
        (Ts, "R_r_out", 3, 6),  # P_r_sys -> P_pa
        (T, "R_pv", 6, 7),  # P_pa -> P_pv
        (Td, "R_l_in", 7, 0),  # P_pv -> P_l_dia
    ]
    for row, (dur, R, up, down) in enumerate(segments, start=1):
        M[row] = sv_l
        M[row, up] -= dur / g(R)
        M[row, down] += dur / g(R)
        rhs[row] = -sv_l_const
    # 8: total stressed volume
    V0_tot = unstressed_volumes(p).sum()
    M[7] = [Cld, 0, Crd, 0, g("C_a"), g("C_v"), g("C_pa"), g("C_pv")]
    rhs[7] = v_total - V0_tot + pth * (Cld + Crd + g("C_pa") + g("C_pv")) + g("C_a") * pth / 3.0
    return M, rhs


def initial_pressures(p: np.ndarray, v_total: float = V_TOTAL_ML) -> np.ndarray:
    """Initial compartment pressures ``[P_l, P_a, P_v, P_r, P_pa, P_pv]`` at t = 0 (mmHg).

    Ventricles start at their diastolic values of the appendix-A system.
    """
    M, rhs = initial_condition_system(p, v_total)
    x = np.linalg.solve(M, rhs)
    return np.array([x[0], x[4], x[5], x[2], x[6], x[7]])


def volumes(t, P: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Compartment volumes (mL) from pressures ``P[..., 6]`` (mmHg) at times ``t`` (s)."""
    C, _ = compliances(t, p)
    return unstressed_volumes(p) + C * (P - pressure_offsets(p))


def valve_states(P: np.ndarray) -> np.ndarray:
    """Open (1) / closed (0) state of each of the six flows for pressures ``P[..., 6]``.

    Non-valve flows are always 1; a valve is open when its upstream pressure exceeds
    the downstream one (ideal diode, no regurgitation).
    """
    dP = P - np.roll(P, -1, axis=-1)
    return np.where(VALVE_MASK == 1, (dP > 0).astype(np.int64), 1)


def flows(P: np.ndarray, p: np.ndarray, states: np.ndarray | None = None) -> np.ndarray:
    """The six flows (mL/s) in flow order for pressures ``P[..., 6]`` (mmHg)."""
    if states is None:
        states = valve_states(P)
    dP = P - np.roll(P, -1, axis=-1)
    return states * conductances(p) * dP


def rhs_pressure(t: float, P: np.ndarray, p: np.ndarray, states: np.ndarray | None = None) -> np.ndarray:
    """Right-hand side dP/dt (mmHg/s) of the paper's six pressure ODEs.

    ``states`` fixes the valve states; by default they follow the indicator functions.
    """
    A, b = linear_system(t, P, p, states)
    return A @ P + b


def linear_system(t: float, P: np.ndarray, p: np.ndarray, states: np.ndarray | None = None):
    """``A(t)`` (1/s) and ``b(t)`` (mmHg/s) of ``dP/dt = A(t) P + b(t)`` (paper eq. 3).

    ``A`` is also the exact Jacobian of the right-hand side wherever the valve states
    are constant. Valve states are taken from ``P`` unless given.
    """
    if states is None:
        states = valve_states(P)
    C, dC = compliances(t, p)
    off = pressure_offsets(p)
    a = states * conductances(p)  # effective conductance of each flow
    A = np.zeros((6, 6))
    for i in range(6):
        k_in, k_out = (i - 1) % 6, i
        # inflow a_in (P_{i-1} - P_i), outflow a_out (P_i - P_{i+1})
        A[i, (i - 1) % 6] += a[k_in]
        A[i, i] -= a[k_in] + a[k_out]
        A[i, (i + 1) % 6] += a[k_out]
        A[i, i] -= dC[i]
        A[i] /= C[i]
    b = dC * off / C
    return A, b


def total_volume(t, P: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Total blood volume ``sum_i V_i`` (mL) for pressures ``P[..., 6]`` at times ``t``."""
    return volumes(t, P, p).sum(axis=-1)
