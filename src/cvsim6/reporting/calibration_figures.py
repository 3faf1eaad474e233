"""Figures of the calibration study (inVAErt beside NPE on simulated EHR-prior cases), drawn
from the ``.npz`` of :func:`cvsim6.studies.calibration.write_figure_data` (its docstring lists
the arrays; all unitless). Computes no diagnostic and loads no network.
"""
from __future__ import annotations

import math

import numpy as np

from cvsim6.reporting.figures import save_figure, subplots

#: Line colour per inverse method.
METHOD_COLORS = {"inVAErt": "tab:blue", "NPE": "tab:orange"}
#: Kolmogorov-Smirnov constant of the 95% band: sup |ECDF - CDF| < 1.358 / sqrt(n).
KS_95 = 1.358


def read_figure_data(figure_data: str) -> dict[str, np.ndarray]:
    """The arrays of a calibration figure-data ``.npz`` (method and parameter names as ``str``)."""
    with np.load(figure_data) as npz:
        return {k: npz[k] for k in npz.files}


def calibration_figures(figure_data: str, coverage_figure: str, rank_figure: str, recovery_figure: str) -> None:
    """Workflow step: the coverage curves (every delta), the SBC rank ECDFs and the recovery
    scatter (at the data's ``figure_noise_level``), each a PNG with a PDF beside it."""
    data = read_figure_data(figure_data)
    draw_coverage(data, coverage_figure)
    draw_rank_ecdf(data, rank_figure)
    draw_recovery(data, recovery_figure)


def draw_coverage(data: dict, path: str) -> None:
    """Per delta: each parameter's empirical coverage against the nominal level (thin), their
    mean (thick) and the joint TARP curve (dashed), per method."""
    levels, deltas, methods = data["coverage_levels"], data["noise_levels"], [str(m) for m in data["methods"]]
    fig, axes = subplots(1, len(deltas), figsize=(3.6 * len(deltas), 3.8), squeeze=False, sharey=True)
    for k, (ax, d) in enumerate(zip(axes[0], deltas)):
        ax.plot([0, 1], [0, 1], color="k", lw=0.8, ls=":")
        for i, m in enumerate(methods):
            cov = data["coverage"][i, k]
            ax.plot(levels, cov, color=METHOD_COLORS[m], lw=0.5, alpha=0.2)
            ax.plot(levels, cov.mean(axis=1), color=METHOD_COLORS[m], lw=2.2,
                    label=f"{m}: marginal (mean of {cov.shape[1]})")
            ax.plot(data["tarp_alpha"][i, k], data["tarp_ecp"][i, k], color=METHOD_COLORS[m], lw=1.4, ls="--",
                    label=f"{m}: TARP (joint)")
        ax.set_title(f"delta = {d:g}")
        ax.set_xlabel("nominal level of the central interval")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("empirical coverage")
    axes[0, -1].legend(fontsize=7, loc="lower right")
    fig.suptitle("Coverage of the true parameters (thin lines: one per parameter; dotted: calibrated)")
    fig.tight_layout()
    save_figure(fig, path)


def _panel_title(ax, name: str, nonid: bool) -> None:
    ax.set_title(name + (" (non-id.)" if nonid else ""), fontsize=9, color="tab:red" if nonid else "k")


def _parameter_grid(n: int, height: float, **kwargs):
    """A figure with one panel per parameter, six per row (the spare panels hidden)."""
    ncols = 6
    nrows = math.ceil(n / ncols)
    fig, axes = subplots(nrows, ncols, figsize=(2.6 * ncols, height * nrows), squeeze=False, **kwargs)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    return fig, axes


def draw_rank_ecdf(data: dict, path: str) -> None:
    """Per parameter, the ECDF of the normalized ranks minus the uniform CDF, with the 95% KS band."""
    names, nonid, methods = data["parameters"], data["non_identifiable"], [str(m) for m in data["methods"]]
    n_samples = int(data["n_samples"])
    fig, axes = _parameter_grid(len(names), 2.1, sharex=True)
    grid = np.linspace(0, 1, 201)
    band = KS_95 / math.sqrt(data["ranks"].shape[1])
    for j, ax in enumerate(list(axes.flat)[:len(names)]):
        ax.fill_between(grid, -band, band, color="0.85", lw=0)
        for i, m in enumerate(methods):
            u = np.sort((data["ranks"][i, :, j] + 0.5) / (n_samples + 1))
            ax.plot(grid, np.searchsorted(u, grid, side="right") / len(u) - grid, color=METHOD_COLORS[m], lw=1.2,
                    label=m)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylim(-1, 1)
        ax.tick_params(labelsize=7)
        _panel_title(ax, str(names[j]), bool(nonid[j]))
    axes.flat[0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"SBC rank ECDF minus uniform, delta = {float(data['figure_noise_level']):g} (gray: 95% band of a "
                 "calibrated sampler; above 0 on the left: true values sit low in the samples)", fontsize=10)
    fig.supxlabel("normalized rank of the true value among the samples", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def draw_recovery(data: dict, path: str) -> None:
    """Per parameter, the posterior mean against the true value (both as fractions of the prior width)."""
    names, nonid, methods = data["parameters"], data["non_identifiable"], [str(m) for m in data["methods"]]
    fig, axes = _parameter_grid(len(names), 2.4)
    theta = data["true_fraction"]
    for j, ax in enumerate(list(axes.flat)[:len(names)]):
        ax.plot([0, 1], [0, 1], color="k", lw=0.6, ls=":")
        for i, m in enumerate(methods):
            ax.scatter(theta[:, j], data["posterior_mean_fraction"][i, :, j], s=3, alpha=0.5, color=METHOD_COLORS[m],
                       label=m, lw=0)
        ax.set_xlim(-0.05, 1.05)
        ax.set_ylim(-0.25, 1.25)
        ax.tick_params(labelsize=7)
        _panel_title(ax, str(names[j]), bool(nonid[j]))
    axes.flat[0].legend(fontsize=7, markerscale=3, loc="upper left")
    fig.suptitle(f"Recovery: posterior mean against the true value, delta = {float(data['figure_noise_level']):g} "
                 "(prior box scaled to [0, 1]; a flat cloud: the data do not inform the parameter)", fontsize=10)
    fig.supxlabel("true value (fraction of the prior width)", fontsize=9)
    fig.supylabel("posterior mean", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
