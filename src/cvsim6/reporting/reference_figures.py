"""Figures of the references: Sobol heatmaps per prior and reference-posterior marginals beside
inVAErt's and NPE's. Drawn from the data files the study steps write
(:mod:`cvsim6.studies.sensitivity`, :mod:`cvsim6.studies.references`)."""
from __future__ import annotations

import numpy as np
import pandas as pd

from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES
from cvsim6.reporting.figures import save_figure, subplots

#: Colours of the three posteriors in the marginals figure.
COLOURS = {"reference": "black", "inVAErt": "tab:blue", "NPE": "tab:orange"}


def sobol_heatmap(sobol: str, figure: str, prior: str) -> None:
    """Workflow step: S1 and ST of the 16 outputs (rows) and 23 parameters (columns) under
    ``prior``, side by side, from the Sobol table (unitless, colour scale 0..1)."""
    df = pd.read_csv(sobol)
    df = df[df["prior"] == prior]
    if df.empty:
        raise ValueError(f"no Sobol indices for prior {prior!r} in {sobol}")
    fig, axes = subplots(1, 2, figsize=(17, 6.5), sharey=True)
    for ax, key in zip(axes, ("S1", "ST")):
        grid = df.pivot(index="output", columns="parameter", values=key).loc[list(OUTPUT_NAMES), list(PARAMETER_NAMES)]
        im = ax.imshow(np.clip(grid.to_numpy(float), 0, 1), vmin=0, vmax=1, cmap="viridis", aspect="auto")
        ax.set_xticks(range(len(PARAMETER_NAMES)), PARAMETER_NAMES, rotation=90, fontsize=8)
        ax.set_yticks(range(len(OUTPUT_NAMES)), OUTPUT_NAMES, fontsize=8)
        ax.set_title(f"{key} ({prior} prior, {int(df['n_base'].max())} base points)")
        for i, j in zip(*np.nonzero(grid.to_numpy(float) >= 0.1)):
            ax.text(j, i, f"{grid.iat[i, j]:.2f}", ha="center", va="center", fontsize=5.5, color="white")
    fig.colorbar(im, ax=axes, shrink=0.8, label="Sobol index (clipped to [0, 1])")
    save_figure(fig, figure)


def reference_marginals(figure_data: str, figure: str, case: str) -> None:
    """Workflow step: the 23 marginals of case ``case`` in prior-box units (0: lower bound, 1:
    upper), the MCMC reference beside inVAErt's and NPE's samples; the true value of a simulated
    case as a dashed line."""
    z = np.load(figure_data)
    if f"reference__{case}" not in z:
        raise ValueError(f"case {case!r} is not among the figure cases in {figure_data}")
    fig, axes = subplots(4, 6, figsize=(15, 9.5))
    bins = np.linspace(-0.1, 1.1, 37)
    truth = z[f"truth__{case}"]
    for j, ax in enumerate(axes.flat):
        if j >= len(PARAMETER_NAMES):
            ax.axis("off")
            continue
        for name, colour in COLOURS.items():
            v = z[f"{name}__{case}"][:, j]
            v = v[np.isfinite(v)]
            if len(v):
                ax.hist(np.clip(v, bins[0], bins[-1]), bins=bins, density=True, histtype="step", color=colour,
                        lw=1.6 if name == "reference" else 1.1, label=f"{name} ({len(v)})")
        if np.isfinite(truth[j]):
            ax.axvline(truth[j], color="crimson", ls="--", lw=1)
        ax.set_title(PARAMETER_NAMES[j], fontsize=9)
        ax.set_yticks([])
        ax.tick_params(labelsize=7)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    axes.flat[-1].legend(handles, labels, fontsize=8, loc="upper left")
    axes.flat[-1].text(0, 0.35, f"case {case}\nx: prior-box units\n(0 lower, 1 upper bound)"
                       + ("\ndashed: true value" if np.isfinite(truth).any() else ""), fontsize=9, va="top")
    fig.suptitle(f"Posterior marginals, case {case}: MCMC reference, inVAErt, NPE")
    fig.tight_layout()
    save_figure(fig, figure)
