"""Figures of the stiffness analysis (paper section 3.1, figures 2-6).

Each function reads the CSVs written by :mod:`cvsim6.model.stiffness` and saves one
figure as PNG (150 dpi) and PDF. Units come from :mod:`cvsim6.registry`.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from cvsim6 import registry
from cvsim6.reporting.figures import subplots

DPI = 150
#: Units from the registry: pressures (mmHg), volumes (mL), compliances (mL/mmHg).
U_P = registry.PARAMETER_BY_NAME["P_th"].unit
U_V = registry.PARAMETER_BY_NAME["V0_l"].unit
U_C = registry.PARAMETER_BY_NAME["C_l_dia"].unit
U_Q = f"{U_V}/s"
#: Valve shading colours of the paper's figure 5.
VALVE_COLORS = {"mitral": "tab:blue", "aortic": "tab:red", "tricuspid": "tab:gray", "pulmonary": "tab:green"}
SR_COLOR = "tab:purple"
COMPARTMENT_LABELS = [f"$P_{{{c}}}$" for c in registry.COMPARTMENTS]


def _save(fig, png: str, pdf: str) -> None:
    for path in (png, pdf):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=DPI, bbox_inches="tight")
    fig.savefig(pdf, bbox_inches="tight")


def _open_intervals(t: np.ndarray, is_open: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) times (s) of the runs where ``is_open`` is 1 on the grid ``t``."""
    d = np.diff(np.concatenate([[0], is_open.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(t[a], t[b]) for a, b in zip(starts, ends)]


def eigenvalue_figure(eigenvalues: str, png: str, pdf: str, zero_eigenvalue_tol: float) -> None:
    """Paper figure 2: the six eigenvalues of A(t) (1/s) over the last two cycles.

    Top: Re(lambda_i) on a symlog axis; bottom: |Re(lambda_i)| on a log axis with the
    zero threshold (exact zeros are drawn at the bottom edge).
    """
    df = pd.read_csv(eigenvalues)
    t = df["t"].to_numpy()
    fig, (ax1, ax2) = subplots(2, 1, figsize=(10.5, 7.5), sharex=True)
    colors = matplotlib.colormaps["viridis"](np.linspace(0, 0.9, 6))
    floor = 1e-19
    lambdas = [c for c in df.columns if c.startswith("lambda_")]  # model.stiffness.LAMBDA_COLUMNS, in order
    for j, c in enumerate(lambdas):
        lam = df[c].to_numpy()
        ax1.plot(t, lam, ".", ms=1.5, color=colors[j], label=rf"$\lambda_{j + 1}$")
        ax2.plot(t, np.maximum(np.abs(lam), floor), ".", ms=1.5, color=colors[j], label=rf"$\lambda_{j + 1}$")
    ax1.set_yscale("symlog", linthresh=1e-3)
    ax1.axhline(0, color="k", lw=0.5)
    ax1.set_ylabel(r"Re $\lambda_i(t)$ (1/s), symlog")
    ax1.set_title("Eigenvalues of the Jacobian A(t) along the reference solution, sorted by |Re| (descending)",
                  fontsize=11)
    ax1.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), markerscale=8, fontsize=10)
    ax2.set_yscale("log")
    ax2.set_ylim(floor / 3, 3e3)
    ax2.axhline(zero_eigenvalue_tol, color="k", ls="--", lw=1,
                label=f"zero\nthreshold\n{zero_eigenvalue_tol:g} 1/s")
    ax2.set_ylabel(r"|Re $\lambda_i(t)$| (1/s)")
    ax2.set_xlabel("t (s)")
    ax2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), markerscale=8, fontsize=10)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.set_xlim(t[0], t[-1])
    fig.tight_layout()
    _save(fig, png, pdf)


def radar_figure(eigenvectors: str, png: str, pdf: str, instant: str) -> None:
    """Paper figures 3-4: radar plots of |Q_j| over (P_l, ..., P_pv), one per eigenvector,
    at the instant ``"SR max"`` or ``"SR min"``."""
    df = pd.read_csv(eigenvectors)
    df = df[df["instant"] == instant].sort_values("index")
    t = float(df["t"].iloc[0])
    angles = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    fig, axes = subplots(1, 6, figsize=(17, 3.8), subplot_kw={"projection": "polar"})
    for ax, (_, row) in zip(axes, df.iterrows()):
        r = np.array([row[f"Q_{c}"] for c in registry.COMPARTMENTS])
        ax.plot(np.append(angles, angles[0]), np.append(r, r[0]), color="tab:blue", lw=1.5)
        ax.fill(angles, r, color="tab:blue", alpha=0.25)
        ax.set_xticks(angles)
        ax.set_xticklabels(COMPARTMENT_LABELS, fontsize=10)
        ax.set_ylim(0, 1)
        ax.set_yticks([0.25, 0.5, 0.75, 1.0])
        ax.set_yticklabels(["", "0.5", "", "1"], fontsize=7)
        j = int(row["index"])
        ax.set_title(rf"$|Q_{j}|$, $\lambda_{j}$ = {row['lambda']:.3g} 1/s", fontsize=10, pad=14)
    fig.suptitle(f"{instant} at t = {t:.4f} s: moduli of the unit eigenvector components of A(t)", y=1.02)
    fig.tight_layout()
    _save(fig, png, pdf)


def sr_dynamics_figure(eigenvalues: str, trajectory: str, png: str, pdf: str) -> None:
    """Paper figure 5: SR(t) (log, twin axis) beside V, P and C of both sides of the heart,
    with the open intervals of the valves shaded (left column: mitral, aortic; right
    column: tricuspid, pulmonary)."""
    eig = pd.read_csv(eigenvalues)
    tr = pd.read_csv(trajectory)
    t = tr["t"].to_numpy()
    panels = [
        ("V_l", f"$V_l$ ({U_V})", "left"), ("V_r", f"$V_r$ ({U_V})", "right"),
        ("P_l", f"$P_l$ ({U_P})", "left"), ("P_r", f"$P_r$ ({U_P})", "right"),
        ("P_a", f"$P_a$ ({U_P})", "left"), ("P_pa", f"$P_{{pa}}$ ({U_P})", "right"),
        ("C_l", f"$C_l$ ({U_C})", "left"), ("C_r", f"$C_r$ ({U_C})", "right"),
    ]
    side_valves = {"left": ("mitral", "aortic"), "right": ("tricuspid", "pulmonary")}
    intervals = {v: _open_intervals(t, tr[f"open_{v}"].to_numpy()) for v in VALVE_COLORS}
    fig, axes = subplots(4, 2, figsize=(13, 12), sharex=True)
    for ax, (col, label, side) in zip(axes.ravel(), panels):
        for v in side_valves[side]:
            for a, b in intervals[v]:
                ax.axvspan(a, b, color=VALVE_COLORS[v], alpha=0.15, lw=0)
        ax.plot(t, tr[col], color="k", lw=1.4)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax2 = ax.twinx()
        ax2.plot(eig["t"], eig["SR"], color=SR_COLOR, lw=0.9)
        ax2.set_yscale("log")
        ax2.set_ylabel("SR (-)", color=SR_COLOR)
        ax2.tick_params(axis="y", colors=SR_COLOR)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
        ax.set_xlim(t[0], t[-1])
    axes[0, 0].set_title("Left heart (mitral, aortic valves)")
    axes[0, 1].set_title("Right heart (tricuspid, pulmonary valves)")
    handles = [Line2D([], [], color="k", lw=1.4, label="model variable (left axis)"),
               Line2D([], [], color=SR_COLOR, lw=1.2, label="stiffness ratio SR(t) (right axis, log)")]
    handles += [Patch(color=c, alpha=0.3, label=f"{v} valve open") for v, c in VALVE_COLORS.items()]
    fig.legend(handles=handles, loc="lower center", ncol=3, bbox_to_anchor=(0.5, -0.04), fontsize=10)
    fig.tight_layout()
    _save(fig, png, pdf)


def rk4_figure(series: str, png: str, pdf: str) -> None:
    """Paper figure 6: P_l, Q_l_out, V_l and total volume sum V of explicit RK4 at the
    fixed steps against Radau over the last two cycles; P_a of the largest step
    dash-dotted in the P_l panel."""
    df = pd.read_csv(series)
    methods = list(dict.fromkeys(df["method"]))
    ref, rk = methods[0], methods[1:]
    colors = dict(zip(rk, ["tab:blue", "tab:orange", "tab:red", "tab:brown", "tab:pink"]))
    panels = [("P_l", f"$P_l$ ({U_P})"), ("Q_l_out", f"$Q_{{l,out}}$ ({U_Q})"),
              ("V_l", f"$V_l$ ({U_V})"), ("V_total", rf"$\sum V$ ({U_V})")]
    fig, axes = subplots(2, 2, figsize=(13, 8.5), sharex=True)
    for ax, (col, label) in zip(axes.ravel(), panels):
        d = df[df["method"] == ref]
        ax.plot(d["t"], d[col], color="k", lw=2.2, label=ref)
        for m in rk:
            d = df[df["method"] == m]
            ax.plot(d["t"], d[col], color=colors[m], lw=1.1, marker="." if len(d) < 200 else None, ms=4, label=m)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    d = df[df["method"] == rk[-1]]
    axes[0, 0].plot(d["t"], d["P_a"], color="tab:green", ls="-.", lw=1.3, label=f"$P_a$, {rk[-1]}")
    axes[0, 0].legend(fontsize=9, loc="upper right")
    axes[1, 1].axhline(registry.V_TOTAL_ML, color="gray", lw=0.8, ls=":")
    axes[1, 1].ticklabel_format(axis="y", useOffset=False)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    tmin, tmax = df["t"].min(), df["t"].max()
    axes[0, 0].set_xlim(tmin, tmax)
    fig.suptitle("Explicit RK4 at fixed steps vs implicit Radau (reference), last two cycles")
    fig.tight_layout()
    _save(fig, png, pdf)
