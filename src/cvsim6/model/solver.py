"""Solving CVSim-6 and extracting the 16 clinical outputs.

Two paths, same outputs (see :mod:`cvsim6.registry`):

``batch`` (default): an array of parameter sets in one call, a compiled (numba)
kernel looping over the batch. Method: the L-stable, stiffly accurate two-stage
SDIRK of Alexander (gamma = 1 - 1/sqrt(2), order 2) at a fixed step of
``T/steps_per_cycle``, integrating the six compartment *volumes* rather than pressures.

Why this method:

* CVSim-6 is stiff (paper section 3.1): ventricle-artery coupling through the small
  outflow resistances gives time constants of ~2 ms at the default parameters and
  ~0.1 ms on the wide EHR prior, so an explicit method would need steps below
  ~T/2500. An L-stable implicit method damps those modes at any step.
* In volume form the right-hand side is ``dV_i/dt = Q_{i-1} - Q_i`` with flows linear
  in pressure ``P_i = (V_i - V0_i)/C_i(t) + off_i``. For fixed valve states each
  implicit stage is therefore one *linear* solve, a symmetric ring-shaped (cyclic
  tridiagonal) 6x6 system, solved in ~40 flops. Total volume is a linear invariant
  and every Runge-Kutta method conserves it exactly (to round-off).
* Accuracy is limited by the valve switches, not by stiffness: the indicator
  functions make the right-hand side discontinuous. The kernel locates each switch
  inside the step (regula falsi on the valve's pressure difference, under the old
  valve state), ends a sub-step there and flips the valve. Minima at valve
  opening (diastolic P_a, P_pa) and volume extrema at valve closure are then nodes
  of the solution; smooth interior extrema are refined with a parabola through
  three nodes. Means are trapezoidal over all nodes of the last cycles.

``reference``: scipy ``solve_ivp(method="Radau")`` on the paper's pressure ODEs, one
set at a time, with tight tolerances, the analytic Jacobian and dense output. Valve
switches are located as solver events and the integration restarted at each one;
extrema are taken from the dense output on a fine grid and refined by bounded
scalar minimization. It is slow (seconds per set) and exists to check the batch path.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar

from cvsim6.model import _kernel
from cvsim6.model import equations as model
from cvsim6.registry import (
    COMPARTMENTS,
    FLOWS,
    N_OUTPUTS,
    OUTPUT_NAMES,
    PARAMETER_INDEX,
    PARAMETER_NAMES,
    VALVES,
    WOOD_TO_DYN,
)

log = logging.getLogger(__name__)

#: Status codes of a simulated row, and their reasons.
STATUS_OK = 0
STATUS_REASONS = {
    0: "ok",
    1: "non-finite output",
    2: "negative compartment volume",
    3: "valve chatter (too many switches in more than 1% of the steps)",
    4: "output outside the physiological range (LVEF not in (0,1) or CO <= 0)",
    5: "total volume not conserved",
    6: "integration failed",
    7: "parameters outside the model's domain (not finite, Hr, a compliance or resistance <= 0, "
       "or r_sys not in (0, 2/3))",
    8: "unphysical parameters (a negative unstressed volume, or a ventricle's systolic compliance "
       "not below its diastolic one)",
}
#: Status of a row whose parameters the equations cannot take (``invalid="flag"``).
STATUS_OUTSIDE_DOMAIN = 7
#: Status of a row whose parameters the equations accept but no circulation has (see
#: :func:`unphysical`): simulated, outputs kept, flagged.
STATUS_UNPHYSICAL = 8

DEFAULT_STEPS_PER_CYCLE = 600
#: Fewest time steps per cycle the batch solver accepts.
MIN_STEPS_PER_CYCLE = 20
DEFAULT_N_CYCLES = 12
DEFAULT_WINDOW_CYCLES = 3

_P = PARAMETER_INDEX
#: Numerical failures of one row; anything else (a compile error, say) propagates.
_ROW_ERRORS = (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError)


class IntegrationError(RuntimeError):
    """The reference integrator gave up on a parameter set (step size underflow, say)."""


#: Numerical failures of one reference solve; a programming error propagates.
_REFERENCE_ERRORS = (IntegrationError, *_ROW_ERRORS)
_V0 = [PARAMETER_INDEX[n] for n in ("V0_l", "V0_a", "V0_v", "V0_r", "V0_pa", "V0_pv")]


def unphysical(params) -> np.ndarray:
    """Boolean mask (N,) of parameter sets the equations accept but no circulation has:
    an unstressed volume < 0 (mL), or ``C_l_sys >= C_l_dia`` or ``C_r_sys >= C_r_dia``
    (a ventricle no stiffer in systole than in diastole does not pump). Such rows are
    simulated and flagged with status 8, not rejected."""
    P = np.atleast_2d(np.asarray(params, dtype=float))
    with np.errstate(invalid="ignore"):
        return ((P[:, _V0] < 0).any(axis=1) | (P[:, _P["C_l_sys"]] >= P[:, _P["C_l_dia"]])
                | (P[:, _P["C_r_sys"]] >= P[:, _P["C_r_dia"]]))


def first_invalid_row(params) -> tuple[int, str | None, str] | None:
    """The first row (0-based) the simulator rejects, its column and why; None when all
    rows are valid.

    ``params`` as for :func:`simulate`; in a DataFrame a blank cell or one that is not a
    number (text) is named too. The reason leaves out the parameter's name:
    ``"'abc' is not a number"``, ``"blank (a number is required)"``, or the check of
    :func:`cvsim6.model.equations.validate_parameters` (``"0.0 mmHg·s/mL must be > 0"``).
    """
    if isinstance(params, pd.DataFrame):
        missing = [n for n in PARAMETER_NAMES if n not in params.columns]
        if missing:
            raise model.ParameterError(f"missing parameter column(s): {', '.join(missing)}")
        raw = params.loc[:, list(PARAMETER_NAMES)]
        num = raw.apply(pd.to_numeric, errors="coerce")
        text = (raw.notna() & num.isna()).to_numpy()
        blank = raw.isna().to_numpy()
        P = num.to_numpy(dtype=float)
    else:
        P = model.as_parameter_array(params)
        text = blank = np.zeros(P.shape, dtype=bool)
    bad = model.outside_domain(P) | text.any(axis=1) | blank.any(axis=1)
    if not bad.any():
        return None
    row = int(np.argmax(bad))
    if text[row].any():
        col = int(np.argmax(text[row]))
        return row, PARAMETER_NAMES[col], f"{raw.iat[row, col]!r} is not a number"
    if blank[row].any():
        return row, PARAMETER_NAMES[int(np.argmax(blank[row]))], "blank (a number is required)"
    try:
        model.validate_parameters(P[row : row + 1])
    except model.ParameterError as exc:
        m = re.match(r"row 0: parameter (\w+) = (.*)$", str(exc))
        return (row, m[1], m[2]) if m else (row, None, re.sub(r"^row 0: ", "", str(exc)))
    raise AssertionError("outside_domain and validate_parameters disagree")  # pragma: no cover


# ----------------------------------------------------------------------------- API
def _check_schedule(steps_per_cycle: int, n_cycles: int, window_cycles: int) -> None:
    if int(steps_per_cycle) < MIN_STEPS_PER_CYCLE:
        raise ValueError(f"steps_per_cycle = {steps_per_cycle} is too small (need >= {MIN_STEPS_PER_CYCLE})")
    if not 1 <= int(window_cycles) < int(n_cycles):
        raise ValueError(f"window_cycles = {window_cycles} must lie in [1, n_cycles = {n_cycles})")


def kernel_is_cached() -> bool:
    """Whether the batch kernel is compiled in this process or cached on disk for this
    version of its source (numba's index file); False when that cannot be told. A first
    call without either compiles it, which takes up to a minute."""
    if _kernel.batch.signatures:
        return True
    try:  # numba's own cache index: empty when missing or written for other source
        return bool(_kernel.batch._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 - a private API: any failure means "cannot tell"
        return False


def simulate_batch(
    params,
    steps_per_cycle: int = DEFAULT_STEPS_PER_CYCLE,
    n_cycles: int = DEFAULT_N_CYCLES,
    window_cycles: int = DEFAULT_WINDOW_CYCLES,
    progress: bool = False,
    chunk_size: int = 1000,
    invalid: str = "raise",
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate an (N, 23) array of parameter sets with the batch SDIRK kernel.

    Returns ``(outputs, status)``: outputs (N, 16) in registry order and units,
    status (N,) integer codes (:data:`STATUS_REASONS`; 0 = ok). A row that fails or
    leaves the physiological range is flagged; the other rows are unaffected. A row with
    :func:`unphysical` parameters is simulated and flagged with status 8 (this takes
    precedence over the other flags: it is their likely cause).
    Rows outside the model's domain (:func:`cvsim6.model.equations.outside_domain`) raise
    :class:`cvsim6.model.equations.ParameterError` naming the row (``invalid="raise"``) or are
    left unsimulated with status 7 (``invalid="flag"``, e.g. for network predictions).
    """
    _check_schedule(steps_per_cycle, n_cycles, window_cycles)
    P = model.as_parameter_array(params)
    if invalid == "raise":
        model.validate_parameters(P)
    elif invalid != "flag":
        raise ValueError(f"invalid must be 'raise' or 'flag', got {invalid!r}")
    n = P.shape[0]
    out = np.full((n, N_OUTPUTS), np.nan)
    status = np.zeros(n, dtype=np.int64)
    bad = model.outside_domain(P)
    if bad.any():
        status[bad] = STATUS_OUTSIDE_DOMAIN
        keep = np.flatnonzero(~bad)
        o, s = simulate_batch(P[keep], steps_per_cycle, n_cycles, window_cycles, progress, chunk_size)
        out[keep], status[keep] = o, s
        return out, status
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n, unit="set", desc="simulate", mininterval=2.0)
    for start in range(0, n, chunk_size):
        sl = slice(start, min(n, start + chunk_size))
        try:
            _kernel.batch(P[sl], int(steps_per_cycle), int(n_cycles), int(window_cycles), out[sl], status[sl])
        except _ROW_ERRORS:  # a row broke the kernel (e.g. singular IC system): isolate it
            for r in range(sl.start, sl.stop):
                try:
                    _kernel.batch(P[r : r + 1], int(steps_per_cycle), int(n_cycles), int(window_cycles),
                           out[r : r + 1], status[r : r + 1])
                except _ROW_ERRORS as exc:
                    log.warning("row %d: integration failed: %s", r, exc)
                    out[r] = np.nan
                    status[r] = 6
        if bar is not None:
            bar.update(sl.stop - sl.start)
    if bar is not None:
        bar.close()
    status[unphysical(P)] = STATUS_UNPHYSICAL
    return out, status


def simulate(
    params,
    method: str = "batch",
    steps_per_cycle: int = DEFAULT_STEPS_PER_CYCLE,
    n_cycles: int = DEFAULT_N_CYCLES,
    window_cycles: int = DEFAULT_WINDOW_CYCLES,
    progress: bool = False,
) -> pd.DataFrame:
    """Simulate parameter sets; return a DataFrame of the 16 outputs plus ``status``.

    ``status`` is ``"ok"`` or the reason a row was flagged. ``method`` is ``"batch"``
    (fast, default) or ``"reference"`` (scipy Radau, seconds per set). A row the model
    cannot take (text or blank cell, a value outside its domain) raises
    :class:`cvsim6.model.equations.ParameterError` naming the row (0-based) and the parameter
    (:func:`first_invalid_row`); unphysical rows are simulated and flagged (status 8).
    """
    if method not in ("batch", "reference"):
        raise ValueError(f"unknown method {method!r}: choose 'batch' or 'reference'")
    bad = first_invalid_row(params)
    if bad is not None:
        row, col, why = bad
        raise model.ParameterError(f"row {row}: parameter {col}: {why}" if col else f"row {row}: {why}")
    if isinstance(params, pd.DataFrame):
        params = params.loc[:, list(PARAMETER_NAMES)].apply(pd.to_numeric)
    if method == "batch":
        out, st = simulate_batch(params, steps_per_cycle, n_cycles, window_cycles, progress=progress)
    elif method == "reference":
        out, st = simulate_reference(params, n_cycles=n_cycles, window_cycles=window_cycles, progress=progress)
    else:
        raise ValueError(f"unknown method {method!r}: choose 'batch' or 'reference'")
    df = pd.DataFrame(out, columns=list(OUTPUT_NAMES))
    df["status"] = [STATUS_REASONS[int(s)] for s in st]
    return df


@dataclass
class Trajectory:
    """Solution of one parameter set at the solver's nodes.

    ``t`` (s), and arrays of shape (n_nodes, 6) in compartment/flow order:
    ``P`` pressures (mmHg), ``V`` volumes (mL), ``Q`` flows (mL/s), ``valves`` the
    state of each flow (1 open) from that node on; ``C`` compliances (mL/mmHg).
    """

    t: np.ndarray
    P: np.ndarray
    V: np.ndarray
    Q: np.ndarray
    C: np.ndarray
    valves: np.ndarray
    params: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        """Tidy table: t, P_*, V_*, Q_*, C_l, C_r and the four valve states."""
        cols = {"t": self.t}
        for i, c in enumerate(COMPARTMENTS):
            cols[f"P_{c}"] = self.P[:, i]
        for i, c in enumerate(COMPARTMENTS):
            cols[f"V_{c}"] = self.V[:, i]
        for i, f in enumerate(FLOWS):
            cols[f] = self.Q[:, i]
        cols["C_l"] = self.C[:, 0]
        cols["C_r"] = self.C[:, 3]
        for name, k in VALVES.items():
            cols[f"valve_{name}"] = self.valves[:, k]
        return pd.DataFrame(cols)


def _trajectory_from_nodes(p: np.ndarray, t: np.ndarray, V: np.ndarray, s: np.ndarray) -> Trajectory:
    C, _ = model.compliances(t, p)
    # the node at the very end of a cycle is evaluated with end-of-cycle compliance
    P = (V - model.unstressed_volumes(p)) / C + model.pressure_offsets(p)
    dP = P - np.roll(P, -1, axis=1)
    Q = s * model.conductances(p) * dP
    return Trajectory(t=t, P=P, V=V, Q=Q, C=C, valves=s.astype(np.int8), params=p)


def simulate_trajectory(
    params,
    steps_per_cycle: int = DEFAULT_STEPS_PER_CYCLE,
    n_cycles: int = DEFAULT_N_CYCLES,
    window_cycles: int = DEFAULT_WINDOW_CYCLES,
) -> tuple[Trajectory, np.ndarray, int]:
    """Batch-path trajectory of one parameter set: ``(trajectory, outputs, status)``."""
    _check_schedule(steps_per_cycle, n_cycles, window_cycles)
    P = model.as_parameter_array(params)
    if P.shape[0] != 1:
        raise ValueError("simulate_trajectory takes one parameter set")
    model.validate_parameters(P)
    p = P[0]
    nmax = n_cycles * (steps_per_cycle + 8 * _kernel.MAX_SWITCHES_PER_STEP) + 1
    rt = np.empty(nmax)
    rV = np.empty((nmax, 6))
    rs = np.empty((nmax, 6), dtype=np.int64)
    out = np.empty((1, N_OUTPUTS))
    st = np.zeros(1, dtype=np.int64)
    nrec = _kernel.lockstep(P, int(steps_per_cycle), int(n_cycles), int(window_cycles), out, st, rt, rV, rs)
    # at a cycle end the local time is T (not 0): compliances are periodic, so equal
    return _trajectory_from_nodes(p, rt[:nrec], rV[:nrec], rs[:nrec]), out[0], int(st[0])


# ----------------------------------------------------------------------------- reference
@dataclass
class ReferenceSegment:
    """A stretch of the reference solution with constant valve states."""

    t0: float
    t1: float
    states: np.ndarray
    sol: object  # scipy OdeSolution: P(t)


class ReferenceSolution:
    """Piecewise dense reference solution P(t) (mmHg) with the valve states of each piece."""

    def __init__(self, p: np.ndarray, segments: list[ReferenceSegment], n_rhs: int):
        self.p = p
        self.segments = segments
        self.n_rhs = n_rhs
        self._t0 = np.array([s.t0 for s in segments])

    @property
    def t_end(self) -> float:
        return self.segments[-1].t1

    def switch_times(self) -> np.ndarray:
        """Segment boundaries (s): valve switches and activation breakpoints."""
        return np.array([s.t0 for s in self.segments[1:]])

    def _segment_index(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self.segments) - 1)

    def pressures(self, t) -> np.ndarray:
        """P(t), shape t.shape + (6,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        idx = self._segment_index(t)
        P = np.empty(t.shape + (6,))
        for j in np.unique(idx):
            m = idx == j
            P[m] = self.segments[j].sol(t[m]).T
        return P

    def states(self, t) -> np.ndarray:
        """Valve states of the six flows in force at t, shape t.shape + (6,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return np.stack([self.segments[j].states for j in self._segment_index(t)])


def reference_solution(
    params, n_cycles: int = DEFAULT_N_CYCLES, rtol: float = 1e-10, atol: float = 1e-10
) -> ReferenceSolution:
    """Solve one parameter set with scipy Radau on the paper's pressure ODEs.

    Valve switches are solver events: the integration stops there, flips the valve
    and restarts, so every piece has a smooth right-hand side. Pieces also break at
    the activation's kinks (t = kT, kT + T_sys, kT + 1.5 T_sys).
    """
    P0 = model.as_parameter_array(params)
    model.validate_parameters(P0)
    p = P0[0]
    T, Ts = model.cycle_times(p)
    t_end = n_cycles * T
    bps = np.unique(np.concatenate([np.arange(n_cycles + 1) * T + d for d in (0.0, Ts, 1.5 * Ts)]))
    bps = bps[(bps > 0) & (bps <= t_end)]
    P = model.initial_pressures(p)
    states = model.valve_states(P)
    t = 0.0
    segments: list[ReferenceSegment] = []
    n_rhs = 0
    valve_ids = np.flatnonzero(model.VALVE_MASK)
    while t < t_end * (1 - 1e-14):
        nxt = bps[bps > t + 1e-12 * T][0]
        st = states.copy()

        def fun(tt, PP, st=st):
            A, b = model.linear_system(tt, PP, p, st)
            return A @ PP + b

        def jac(tt, PP, st=st):
            return model.linear_system(tt, PP, p, st)[0]

        events = []
        for k in valve_ids:
            kp = (k + 1) % 6

            def ev(tt, PP, k=k, kp=kp):
                return PP[k] - PP[kp]

            ev.terminal = True
            ev.direction = -1.0 if st[k] == 1 else 1.0
            events.append(ev)
        sol = solve_ivp(fun, (t, nxt), P, method="Radau", rtol=rtol, atol=atol, jac=jac,
                        dense_output=True, events=events)
        if sol.status < 0:
            raise IntegrationError(f"Radau failed at t = {t:.6g} s: {sol.message}")
        n_rhs += sol.nfev
        if sol.status == 1:
            hits = [(te[0], j) for j, te in enumerate(sol.t_events) if len(te)]
            t_new, j = min(hits)
            k = valve_ids[j]
            P = sol.y_events[j][0].copy()
            states = states.copy()
            states[k] = 1 - states[k]
        else:
            t_new = nxt
            P = sol.y[:, -1].copy()
        segments.append(ReferenceSegment(t, t_new, st, sol.sol))
        t = t_new
    return ReferenceSolution(p, segments, n_rhs)


def reference_outputs(sol: ReferenceSolution, window_cycles: int = DEFAULT_WINDOW_CYCLES,
                      grid_per_segment: int = 64) -> np.ndarray:
    """The 16 outputs from a dense reference solution (registry order and units).

    Extrema: each piece of the window sampled on ``grid_per_segment`` points (its ends
    included, so valve-switch kinks are exact), the best sample refined by bounded
    scalar optimization of the dense output. Means: 12-point Gauss-Legendre per piece.
    """
    p = sol.p
    T, _ = model.cycle_times(p)
    t_end = sol.t_end
    t_win = t_end - window_cycles * T
    xg, wg = np.polynomial.legendre.leggauss(12)
    integ = np.zeros(6)
    best = {}  # quantity -> [max, min]

    def quantity(seg, tt, j):
        P = seg.sol(tt)
        if j == 3:  # V_l
            C, _ = model.compliances(tt, p)
            return model.unstressed_volumes(p)[0] + C[..., 0] * (P[0] - model.pressure_offsets(p)[0])
        return P[(1, 3, 4)[j]]

    for seg in sol.segments:
        a, b = max(seg.t0, t_win), seg.t1
        if b <= a:
            continue
        tq = 0.5 * (b - a) * xg + 0.5 * (a + b)
        integ += 0.5 * (b - a) * (seg.sol(tq) * wg).sum(axis=1)
        tt = np.linspace(a, b, grid_per_segment)
        for j in range(4):
            q = quantity(seg, tt, j)
            for sign, slot in ((1.0, 0), (-1.0, 1)):
                i = int(np.argmax(sign * q))
                val = q[i]
                if True:  # refine around the best sample (one-sided at a piece's ends)
                    lo_, hi_ = tt[max(i - 1, 0)], tt[min(i + 1, len(tt) - 1)]
                    res = minimize_scalar(lambda s_: -sign * float(quantity(seg, np.array([s_]), j)[0]),
                                          bounds=(lo_, hi_), method="bounded",
                                          options={"xatol": 1e-12 * T})
                    val = max(sign * val, -res.fun) * sign
                cur = best.setdefault(j, [-np.inf, np.inf])
                if slot == 0:
                    cur[0] = max(cur[0], val)
                else:
                    cur[1] = min(cur[1], val)
    means = integ / (t_end - t_win)
    Pend = sol.pressures(t_end)[0]
    mean_Pa, mean_Pv, mean_Ppa, mean_Ppv = means[1], means[2], means[4], means[5]
    Ra = p[_P["R_a"]]
    co = (mean_Pa - mean_Pv) / Ra * 60.0 / 1000.0
    Vsys, Vdia = best[3][1], best[3][0]
    return np.array([
        p[_P["Hr"]], best[0][0], best[0][1], best[1][0], best[1][1], best[2][0], best[2][1],
        Pend[3], mean_Ppv, mean_Pv, Vsys, Vdia, (Vdia - Vsys) / Vdia, co,
        (mean_Pa - mean_Pv) / co * WOOD_TO_DYN, (mean_Ppa - mean_Ppv) / co * WOOD_TO_DYN,
    ])


def simulate_reference(
    params,
    n_cycles: int = DEFAULT_N_CYCLES,
    window_cycles: int = DEFAULT_WINDOW_CYCLES,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Reference outputs of each row (scipy Radau), same contract as :func:`simulate_batch`.

    A row whose integration fails numerically (:class:`IntegrationError`, a singular
    system) gets status 6; any other exception is a bug and propagates."""
    P = model.as_parameter_array(params)
    model.validate_parameters(P)
    out = np.full((P.shape[0], N_OUTPUTS), np.nan)
    status = np.zeros(P.shape[0], dtype=np.int64)
    rows = range(P.shape[0])
    if progress:
        from tqdm import tqdm

        rows = tqdm(rows, unit="set", desc="reference")
    for r in rows:
        try:
            sol = reference_solution(P[r], n_cycles=n_cycles, rtol=rtol, atol=atol)
            out[r] = reference_outputs(sol, window_cycles)
        except _REFERENCE_ERRORS as exc:
            log.warning("row %d: reference integration failed: %s", r, exc)
            status[r] = 6
            continue
        if not np.isfinite(out[r]).all():
            status[r] = 1
        elif not (0 < out[r, 12] < 1 and out[r, 13] > 0):
            status[r] = 4
    status[unphysical(P)] = STATUS_UNPHYSICAL
    return out, status
