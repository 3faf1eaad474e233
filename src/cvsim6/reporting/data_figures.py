"""Histograms of a study's training data, drawn from the bin counts that
:func:`cvsim6.data.datasets.histogram_counts` writes (CSV: ``column``, ``bin``, ``left``,
``right``, ``count``; edges in the column's registry unit). Reads no dataset, runs no simulation.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.ticker import MaxNLocator

from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES
from cvsim6.reporting.figures import label, save_figure, subplots

#: Bar colour of every histogram.
BAR_COLOR = "#3b75af"


def read_histogram_counts(counts: str | Path) -> pd.DataFrame:
    """The bin counts CSV (pandas reads its edges back to the last bit)."""
    return pd.read_csv(counts)


def plot_histograms(counts: str, outputs_figure: str, inputs_figure: str, study: str) -> None:
    """Workflow step: the histograms of the 16 outputs and of the 23 inputs of ``study``
    (PNG, and PDF beside each), from its bin counts ``counts``."""
    table = read_histogram_counts(counts)
    n_sets = int(table.loc[table["column"] == table["column"].iloc[0], "count"].sum())
    histogram_grid(table, OUTPUT_NAMES, outputs_figure, title=f"{study} study: outputs ({n_sets:,} sets)")
    histogram_grid(table, PARAMETER_NAMES, inputs_figure, title=f"{study} study: inputs ({n_sets:,} sets)")


def histogram_grid(counts: pd.DataFrame, columns: Sequence[str], path: str | Path, title: str = "",
                   ncols: int = 4) -> None:
    """A grid of histograms, one per name in ``columns``, from the bin counts ``counts``
    (:func:`read_histogram_counts`), x axes labelled with units."""
    n = len(columns)
    nrows = math.ceil(n / ncols)
    fig, axes = subplots(nrows, ncols, figsize=(3.2 * ncols, 2.4 * nrows), squeeze=False)
    for ax, col in zip(axes.flat, columns):
        bins = counts[counts["column"] == col].sort_values("bin")
        edges = np.r_[bins["left"].to_numpy(), bins["right"].to_numpy()[-1]]
        # one sample at each left edge, weighted by its count: the bars of the original data
        ax.hist(bins["left"].to_numpy(), bins=edges, weights=bins["count"].to_numpy(), color=BAR_COLOR, alpha=0.85)
        ax.set_xlabel(label(col), fontsize=9)
        ax.tick_params(labelsize=8)
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.set_yticks([])
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title, fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 0.98) if title else None)
    save_figure(fig, path)
