"""Figures of the structural identifiability study (paper section 3.3, figures 7-10).

Each function reads the data files that :mod:`cvsim6.studies.structural` writes (CSV, JSON)
and saves one figure as PNG (150 dpi) and PDF beside it; nothing here simulates or loads a
network. Units: registry units (pressures mmHg, volumes mL).
"""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from matplotlib import colormaps
import numpy as np
import pandas as pd

from cvsim6.registry import OUTPUT_BY_NAME, OUTPUT_INDEX, OUTPUT_NAMES, PARAMETER_NAMES
from cvsim6.reporting.figures import save_figure, subplots

#: The four trajectory panels: traced column and the systolic and diastolic outputs in y*
#: drawn as its targets.
PANELS = (("P_a", "P_a_sys", "P_a_dia"), ("P_r", "P_r_sys", "P_r_dia"),
          ("P_pa", "P_pa_sys", "P_pa_dia"), ("V_l", "V_l_sys", "V_l_dia"))


def read_observation(observation: str) -> np.ndarray:
    """y* (16,) from the observation table (column ``y*``), registry units."""
    return pd.read_csv(observation)["y*"].to_numpy(float)


def draw_traces(axes, traces: pd.DataFrame, colors: Sequence) -> None:
    """One curve per ``set`` of ``traces`` (columns ``set``, ``t_over_T`` and the panels'
    quantities) in each of the four panels, in the colour ``colors[set]``."""
    axes = list(axes)  # e.g. axes.flat: an iterator that one pass would exhaust
    for i, rows in traces.groupby("set", sort=True):
        for ax, (name, _, _) in zip(axes, PANELS):
            ax.plot(rows["t_over_T"].to_numpy(), rows[name].to_numpy(), color=colors[i], lw=0.8, alpha=0.8)


def draw_targets(axes, y_star: np.ndarray, observed: np.ndarray | None = None) -> None:
    """Dashed lines at the systolic and diastolic targets in y* (those ``observed``, all if
    None), axis labels with units, grid."""
    for ax, (name, hi, lo) in zip(list(axes), PANELS):
        for out in (hi, lo):
            j = OUTPUT_INDEX[out]
            if observed is None or observed[j]:
                ax.axhline(y_star[j], color="k", ls="--", lw=1)
        ax.set_ylabel(f"{name} ({OUTPUT_BY_NAME[hi].unit})")
        ax.set_xlabel("t / T (last cycle)")
        ax.grid(alpha=0.3)


def manifold_trajectories_figure(traces: str, observation: str, summary: str, figure: str, n_traces: int) -> None:
    """Paper figure 7: the last cycle of the first ``n_traces`` decoded sets for y* (viridis,
    by set), the targets in y* dashed; ``summary`` gives how many sets were decoded."""
    n = json.loads(Path(summary).read_text())["n"]
    cmap = colormaps["viridis"]
    fig, axes = subplots(2, 2, figsize=(11, 7))
    draw_traces(axes.flat, pd.read_csv(traces), [cmap(i / max(1, n_traces - 1)) for i in range(n_traces)])
    draw_targets(axes.flat, read_observation(observation))
    fig.suptitle(f"The first {n_traces} of {n} decoded parameter sets for y*, those inside the "
                 "model's domain (dashed: targets in y*)")
    fig.tight_layout()
    save_figure(fig, figure)


def missing_data_figure(traces: str, observation: str, figure: str, missing: list, top_k: int,
                        n_latent: int) -> None:
    """Paper figure 10: the decoded sets of each of the ``top_k`` completions of y* without
    ``missing`` (one colour per completion), the observed targets dashed."""
    df = pd.read_csv(traces)
    y_star = read_observation(observation)
    observed = np.array([name not in missing for name in OUTPUT_NAMES])
    colors = colormaps["tab10"].colors
    fig, axes = subplots(2, 2, figsize=(11, 7))
    for g in range(top_k):  # the targets after each completion's traces: the figure's drawing order
        draw_traces(axes.flat, df[df["completion"] == g + 1], [colors[g]] * n_latent)
        draw_targets(axes.flat, y_star, observed=observed)
    for g in range(top_k):
        axes.flat[0].plot([], [], color=colors[g], label=f"completion {g + 1}")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(f"Missing data: {top_k} completions x {n_latent} latent draws (dashed: observed targets)")
    fig.tight_layout()
    save_figure(fig, figure)


def parallel_coordinates_figure(lines: str, summary: str, figure: str) -> None:
    """Paper figure 8: parallel coordinates of the manifold samples, two rows, each axis over
    the limits in ``summary`` (prior bounds +5%, printed at its ends)."""
    v = pd.read_csv(lines)[list(PARAMETER_NAMES)].to_numpy(float)
    info = json.loads(Path(summary).read_text())
    lo, hi = np.array([info["axis_limits"][name] for name in PARAMETER_NAMES]).T
    u = (v - lo) / (hi - lo)
    rows = [list(range(0, 12)), list(range(11, 23))]  # R_l_in (index 11) in both rows
    fig, axes = subplots(2, 1, figsize=(14, 7))
    for ax, idx in zip(axes, rows):
        x = np.arange(len(idx))
        for line in u[:, idx]:
            ax.plot(x, line, color="tab:blue", alpha=0.25, lw=0.8)
        for xi, j in zip(x, idx):
            ax.axvline(xi, color="k", lw=0.6)
            ax.text(xi, 1.02, f"{hi[j]:.3g}", ha="center", fontsize=7)
            ax.text(xi, -0.06, f"{lo[j]:.3g}", ha="center", fontsize=7, va="top")
        ax.set_xticks(x)
        ax.set_xticklabels([PARAMETER_NAMES[j] for j in idx], fontsize=9)
        ax.set_yticks([])
        ax.set_ylim(-0.12, 1.08)
        ax.set_xlim(-0.3, len(idx) - 0.7)
        for side in ("top", "right", "left"):
            ax.spines[side].set_visible(False)
    fig.suptitle(f"Non-identifiable manifold of y*: {len(v)} decoded parameter sets "
                 f"(axes span the prior bounds +5%; units as the input table; {info['outside_domain']} sets "
                 "outside the model's domain left out)")
    fig.tight_layout()
    save_figure(fig, figure)


def manifold_svd_figure(csv: str, summary: str, figure: str) -> None:
    """Paper figure 9: singular values and cumulative energy of the manifold samples, the
    modes reaching the summary's energy level marked."""
    df = pd.read_csv(csv)
    info = json.loads(Path(summary).read_text())
    level, n, e = info["level"], info["modes"], info["energy"]
    k, s, ce = df["mode"].to_numpy(), df["singular_value"].to_numpy(), df["cumulative_energy"].to_numpy()
    fig, (a, b) = subplots(1, 2, figsize=(11, 4))
    a.semilogy(k, s, "o-")
    a.set_xlabel("mode")
    a.set_ylabel("singular value (standardized samples)")
    b.plot(k, ce, "o-")
    b.axhline(level, color="gray", ls="--")
    b.axvline(n, color="tab:red", ls=":")
    b.annotate(f"{n} modes: {e:.2%}", (n, e), textcoords="offset points", xytext=(8, -18))
    b.set_xlabel("modes kept")
    b.set_ylabel("cumulative energy")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.suptitle(f"SVD of {info['n_samples']:,} standardized parameter sets on the manifold of y* "
                 "(paper: 12 modes, 99.28%)")
    fig.tight_layout()
    save_figure(fig, figure)


def jacobian_spectra_figure(spectra: str, figure: str, rank_rtol: float) -> None:
    """Normalized singular values sigma_k / sigma_1 of the scaled Jacobian at each point
    (one row of ``spectra`` each), the rank threshold ``rank_rtol`` dashed."""
    sv = pd.read_csv(spectra).to_numpy(float)
    fig, ax = subplots(figsize=(7, 4))
    for s in sv:
        ax.semilogy(np.arange(1, len(s) + 1), s / s[0], color="tab:blue", alpha=0.3)
    ax.axhline(rank_rtol, color="tab:red", ls="--", label=f"rank threshold {rank_rtol:g}")
    ax.set_xlabel("singular value index")
    ax.set_ylabel("sigma_k / sigma_1 (scaled Jacobian)")
    ax.set_title(f"Jacobian spectra at {len(sv)} points of the manifold of y*")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, figure)
