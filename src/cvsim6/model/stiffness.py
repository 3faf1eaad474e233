"""Stiffness analysis of CVSim-6 at the default parameters (paper section 3.1).

For fixed valve states the pressure ODE is linear, ``dP/dt = A(t) P + b(t)``, and
``A(t)`` (1/s, :func:`cvsim6.model.equations.linear_system`) is its exact Jacobian. Along the
Radau reference trajectory we eigen-decompose ``A(t)`` with the valve states in
force and form the stiffness ratio

    SR(t) = max_i |Re l_i| / (min_{i: |Re l_i| >= zero_tol} |Re l_i| + sr_tol),

where an eigenvalue with ``|Re l| < zero_tol`` counts as zero (a conserved
quantity of a decoupled part of the circuit) and is skipped.

Why zeros appear: with the dC/dt terms dropped, ``A = C^-1 G`` with ``G`` the
(negative semi-definite) conductance Laplacian of the circuit. Every connected
group of compartments (closed valves cut the ring) contributes one zero
eigenvalue (its volume is conserved); dC/dt shifts it slightly. At peak
activation (t mod T = T_sys) dC/dt = 0, so the ejecting ventricle-artery-vein
chains have eigenvalues that pass through zero there, and the sampled SR peaks
at the grid point nearest that instant (its value ~ 1/distance).

Everything is in mmHg, mL and s; eigenvalues in 1/s.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.model import equations as model
from cvsim6 import paper_values
from cvsim6 import registry
from cvsim6.model import solver
from cvsim6 import table_files

log = logging.getLogger(__name__)

#: Cycles simulated (as the paper) and cycles analysed at the end of the run.
N_CYCLES = solver.DEFAULT_N_CYCLES
N_LAST = 2
#: Eigenvalue column names, sorted by |Re| descending.
LAMBDA_COLUMNS = tuple(f"lambda_{i}" for i in range(1, 7))


# ----------------------------------------------------------------------------- core
def sorted_eigen(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (1/s) and unit eigenvectors (columns) of ``A``, by |Re| descending."""
    lam, Q = np.linalg.eig(A)
    order = np.argsort(-np.abs(lam.real), kind="stable")
    return lam[order], Q[:, order]


def stiffness_ratio(re_lambdas, zero_tol: float = 1e-10, sr_tol: float = 1e-14) -> np.ndarray:
    """Stiffness ratio for rows of real parts ``re_lambdas[..., n]`` (dimensionless).

    ``max |Re l| / (min non-zero |Re l| + sr_tol)``; ``|Re l| < zero_tol`` counts as
    zero. A row whose eigenvalues are all zero gives NaN.
    """
    a = np.abs(np.asarray(re_lambdas, dtype=float))
    nonzero = np.where(a >= zero_tol, a, np.inf)
    lo = nonzero.min(axis=-1)
    hi = a.max(axis=-1)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(lo), hi / (lo + sr_tol), np.nan)


def analysis_times(p: np.ndarray, samples_per_cycle: int, n_cycles: int = N_CYCLES,
                   n_last: int = N_LAST) -> np.ndarray:
    """Uniform grid (s) over the last ``n_last`` cycles, ``samples_per_cycle`` per cycle, ends included."""
    T, _ = model.cycle_times(p)
    k = np.arange(n_last * samples_per_cycle + 1)
    return (n_cycles - n_last) * T + k * (T / samples_per_cycle)


def eigen_series(sol: solver.ReferenceSolution, t: np.ndarray, zero_tol: float, sr_tol: float) -> pd.DataFrame:
    """Eigenvalues of A(t) along ``sol`` at times ``t`` (s) with the solution's valve states.

    Columns: ``t`` (s), ``lambda_1..6`` (Re, 1/s, |Re| descending), ``max_abs_imag``
    (1/s), ``SR`` (-).
    """
    P = sol.pressures(t)
    S = sol.states(t)
    lam = np.empty((t.size, 6), dtype=complex)
    for i, ti in enumerate(t):
        A, _ = model.linear_system(ti, P[i], sol.p, S[i])
        lam[i], _ = sorted_eigen(A)
    df = pd.DataFrame({"t": t})
    for j, c in enumerate(LAMBDA_COLUMNS):
        df[c] = lam[:, j].real
    df["max_abs_imag"] = np.abs(lam.imag).max(axis=1)
    df["SR"] = stiffness_ratio(lam.real, zero_tol, sr_tol)
    return df


def trajectory_frame(sol: solver.ReferenceSolution, t: np.ndarray) -> pd.DataFrame:
    """Pressures (mmHg), volumes (mL), ventricular compliances (mL/mmHg), flows (mL/s)
    and valve states (1 open) of ``sol`` at times ``t`` (s)."""
    p = sol.p
    P = sol.pressures(t)
    S = sol.states(t)
    V = model.volumes(t, P, p)
    C, dC = model.compliances(t, p)
    Q = model.flows(P, p, S)
    df = pd.DataFrame({"t": t})
    for j, c in enumerate(registry.COMPARTMENTS):
        df[f"P_{c}"] = P[:, j]
    for j, c in enumerate(registry.COMPARTMENTS):
        df[f"V_{c}"] = V[:, j]
    df["V_total"] = V.sum(axis=1)
    for j, c in ((0, "l"), (3, "r")):
        df[f"C_{c}"] = C[:, j]
        df[f"dC_{c}"] = dC[:, j]
    for j, f in enumerate(registry.FLOWS):
        df[f] = Q[:, j]
    for name, k in registry.VALVES.items():
        df[f"open_{name}"] = S[:, k].astype(int)
    return df


def rc_constants(t: float, p: np.ndarray) -> dict[str, float]:
    """Outflow RC constants (s) of both ventricles at time ``t``:
    ``R C_j C_k / (C_j + C_k)`` with (R_l_out, C_l(t), C_a) and (R_r_out, C_r(t), C_pa)."""
    I = registry.PARAMETER_INDEX
    C, _ = model.compliances(np.array([t]), p)
    Cl, Cr = C[0, 0], C[0, 3]
    Ca, Cpa = p[I["C_a"]], p[I["C_pa"]]
    return {
        "RC_left": p[I["R_l_out"]] * Cl * Ca / (Cl + Ca),
        "RC_right": p[I["R_r_out"]] * Cr * Cpa / (Cr + Cpa),
    }


# ----------------------------------------------------------------------------- rules
def eigen_analysis(eigenvalues: str, trajectory: str, rtol: float, samples_per_cycle: int,
                   zero_eigenvalue_tol: float, sr_tol: float) -> None:
    """Rule ``stiffness_eigen``: solve the reference (12 cycles, Radau at ``rtol``) and
    write the eigenvalue/SR series and the trajectory over the last two cycles (CSV)."""
    p = registry.default_parameters()
    sol = solver.reference_solution(p, n_cycles=N_CYCLES, rtol=rtol, atol=rtol)
    t = analysis_times(p, int(samples_per_cycle))
    eig = eigen_series(sol, t, zero_eigenvalue_tol, sr_tol)
    log.info("max |Im lambda| over the window: %.3g 1/s", eig["max_abs_imag"].max())
    for path, df in ((eigenvalues, eig), (trajectory, trajectory_frame(sol, t))):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(path, index=False)


def extreme_rows(eig: pd.DataFrame) -> dict[str, int]:
    """Row positions of the maximum and minimum SR in the eigenvalue series."""
    sr = eig["SR"].to_numpy()
    return {"SR max": int(np.nanargmax(sr)), "SR min": int(np.nanargmin(sr))}


def extremes(eigenvalues: str, trajectory: str, eigenvectors: str, csv: str, md: str,
             zero_eigenvalue_tol: float, sr_tol: float) -> None:
    """Rule ``stiffness_extremes``: eigenvectors at the SR extremes and the comparison table.

    ``eigenvectors`` (CSV): per instant and eigenvalue index, the eigenvalue (1/s) and
    the moduli of the unit eigenvector's components over P_l..P_pv. ``csv``/``md``:
    ours beside the paper's values (t, eigenvalues, SR, tau = 1/|l| and outflow RC).
    """
    p = registry.default_parameters()
    eig = pd.read_csv(eigenvalues)
    traj = pd.read_csv(trajectory)
    vec_rows, table = [], []
    for instant, row in extreme_rows(eig).items():
        t = float(traj["t"].iloc[row])
        P = traj[[f"P_{c}" for c in registry.COMPARTMENTS]].iloc[row].to_numpy()
        states = np.ones(6, dtype=np.int64)
        for name, k in registry.VALVES.items():
            states[k] = int(traj[f"open_{name}"].iloc[row])
        A, _ = model.linear_system(t, P, p, states)
        lam, Q = sorted_eigen(A)
        for j in range(6):
            vec_rows.append({"instant": instant, "t": t, "index": j + 1, "lambda": lam[j].real,
                             "lambda_imag": lam[j].imag,
                             **{f"Q_{c}": abs(Q[i, j]) for i, c in enumerate(registry.COMPARTMENTS)}})
        paper = paper_values.STIFFNESS_EXTREMES[instant]
        sr = float(stiffness_ratio(lam.real, zero_eigenvalue_tol, sr_tol))
        sr_paper = float(stiffness_ratio(np.array(paper["lambdas"]), zero_eigenvalue_tol, sr_tol))
        open_valves = ", ".join(n for n, k in registry.VALVES.items() if states[k]) or "none"
        T, Ts = model.cycle_times(p)
        table.append((instant, "t (s)", f"{t:.4f}", f"{paper['t']:.3f}"))
        table.append((instant, "(t mod T) / T_sys (-)", f"{(t % T) / Ts:.4f}", f"{(paper['t'] % T) / Ts:.4f}"))
        table.append((instant, "open valves", open_valves, ""))
        for j in range(6):
            table.append((instant, f"lambda_{j + 1} (1/s)", lam[j].real, paper["lambdas"][j]))
        table.append((instant, "SR (-)", sr, sr_paper))
        rc = rc_constants(t, p)
        for j, key in ((0, "RC_left"), (1, "RC_right")):
            tau_p = paper["tau"][j]
            table.append((instant, f"tau_{j + 1} = 1/abs(lambda_{j + 1}) (s)", 1.0 / abs(lam[j].real),
                          tau_p if tau_p is not None else 1.0 / abs(paper["lambdas"][j])))
        table.append((instant, "RC left outflow R_l_out C_l C_a/(C_l+C_a) (s)", rc["RC_left"], ""))
        table.append((instant, "RC right outflow R_r_out C_r C_pa/(C_r+C_pa) (s)", rc["RC_right"], ""))
        log.info("%s at t = %.5f s: lambda = %s, SR = %.4g", instant, t, np.array2string(lam.real, precision=5), sr)
    Path(eigenvectors).parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(vec_rows).to_csv(eigenvectors, index=False)
    df = pd.DataFrame(table, columns=["Instant", "Quantity", "This work", "Paper"])
    table_files.write_table(df, csv, md, caption="Eigenvalues of A(t) at the extremes of SR(t), last two cycles "
                       "(paper figures 3-4; paper SR recomputed from its eigenvalues with the same rule)")


# ----------------------------------------------------------------------------- RK4
def rk4(p: np.ndarray, h: float, n_cycles: int = N_CYCLES) -> tuple[np.ndarray, np.ndarray]:
    """Classical explicit RK4 on the pressure ODE with fixed step ``h`` (s).

    Valve states follow the indicator functions at every stage evaluation
    (:func:`cvsim6.model.equations.rhs_pressure` with ``states=None``). Returns node times (s)
    and pressures (mmHg), shape (n+1,) and (n+1, 6). Non-finite values stop the run
    (the rest is NaN).
    """
    T, _ = model.cycle_times(p)
    n = int(round(n_cycles * T / h))
    t = np.arange(n + 1) * h
    P = np.full((n + 1, 6), np.nan)
    P[0] = model.initial_pressures(p)
    f = model.rhs_pressure
    with np.errstate(all="ignore"):
        for i in range(n):
            ti, y = t[i], P[i]
            k1 = f(ti, y, p)
            k2 = f(ti + h / 2, y + h / 2 * k1, p)
            k3 = f(ti + h / 2, y + h / 2 * k2, p)
            k4 = f(ti + h, y + h * k3, p)
            P[i + 1] = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            if not np.isfinite(P[i + 1]).all():
                log.warning("RK4 h = %g s diverged at t = %.4g s", h, t[i + 1])
                break
    return t, P


def _series(method: str, t: np.ndarray, P: np.ndarray, p: np.ndarray, states=None) -> pd.DataFrame:
    Q = model.flows(P, p, states)
    V = model.volumes(t, P, p)
    return pd.DataFrame({"method": method, "t": t, "P_l": P[:, 0], "P_a": P[:, 1],
                         "Q_l_out": Q[:, 0], "V_l": V[:, 0], "V_total": V.sum(axis=1)})


def rk4_study(series: str, csv: str, md: str, rtol: float, rk4_steps: list[float],
              samples_per_cycle: int) -> None:
    """Rule ``stiffness_rk4``: RK4 at each step size (s) against the Radau reference.

    ``series`` (CSV, long format, column ``method``): P_l, P_a (mmHg), Q_l_out (mL/s),
    V_l, V_total (mL) over the last two cycles, the reference on a uniform grid of
    ``samples_per_cycle`` per cycle. ``csv``/``md``: per step size, max |sum V - 5000|
    (mL, all 12 cycles), max |P_l - P_l,ref| (mmHg, last two cycles) and h |lambda_1|max.
    """
    p = registry.default_parameters()
    T, _ = model.cycle_times(p)
    t0 = (N_CYCLES - N_LAST) * T
    sol = solver.reference_solution(p, n_cycles=N_CYCLES, rtol=rtol, atol=rtol)
    tr = analysis_times(p, int(samples_per_cycle))
    frames = [_series("Radau (reference)", tr, sol.pressures(tr), p, sol.states(tr))]
    # fastest eigenvalue over the window, for the RK4 stability number h |lambda|
    Pr, Sr = sol.pressures(tr), sol.states(tr)
    lam_max = max(np.abs(np.linalg.eigvals(model.linear_system(ti, Pr[i], p, Sr[i])[0]).real).max()
                  for i, ti in enumerate(tr[:: max(1, int(samples_per_cycle) // 400)]))
    rows = []
    for h in rk4_steps:
        t, P = rk4(p, float(h))
        dv = np.abs(model.total_volume(t, P, p) - registry.V_TOTAL_ML)
        last = t >= t0 - 1e-9
        err = np.abs(P[last, 0] - sol.pressures(t[last])[:, 0])
        rows.append({"Step h (s)": float(h), "Steps per cycle": float(T / float(h)),
                     "h max abs(lambda_1) (-)": float(h * lam_max),
                     "max abs(sum V - 5000) (mL)": float(np.nanmax(dv)) if np.isfinite(dv).any() else np.nan,
                     "sum V - 5000 at t_end (mL)": float(model.total_volume(t[-1], P[-1], p) - registry.V_TOTAL_ML),
                     "max abs(P_l - P_l_ref), last 2 cycles (mmHg)": float(np.nanmax(err))})
        frames.append(_series(f"RK4 h = {h:g} s", t[last], P[last], p))
        log.info("RK4 h = %g s: %s", h, rows[-1])
    Path(series).parent.mkdir(parents=True, exist_ok=True)
    pd.concat(frames, ignore_index=True).to_csv(series, index=False)
    table_files.write_table(pd.DataFrame(rows), csv, md,
                       caption="Explicit RK4 at fixed steps vs Radau: volume drift and left-ventricular pressure error "
                       "(RK4 is stable on the negative real axis only for h abs(lambda) < 2.79)")
