"""Figures of the trained networks' evaluation (paper appendix C and figure 10).

Each function reads data files written by :mod:`cvsim6.studies.evaluation` (and the
validation split) and saves one figure as PNG (150 dpi) and PDF beside it; nothing here
loads a network.
"""
from __future__ import annotations

import json
from pathlib import Path

from matplotlib import colormaps
import numpy as np
import pandas as pd

from cvsim6.registry import OUTPUT_NAMES
from cvsim6.reporting.figures import label, save_figure, subplots


def read_outputs(path: str) -> np.ndarray:
    """The 16 output columns (registry order and units) of a Parquet dataset: (N, 16) float64."""
    return pd.read_parquet(path, columns=list(OUTPUT_NAMES)).to_numpy(np.float64)


def emulator_l2_histogram(errors: str, summary: str, figure: str) -> None:
    """Histogram of the emulator's relative l2 error (%) on the validation sets, the max and
    mean (and the paper's max, if any) from ``summary`` in the title."""
    err = pd.read_csv(errors)["rel_l2_error"].to_numpy(float)
    info = json.loads(Path(summary).read_text())
    paper = info["paper_max"]
    fig, ax = subplots(figsize=(6.5, 4))
    ax.hist(100 * err, bins=60, color="#3b75af")
    ax.set_xlabel("relative l2 error of the emulator (%)")
    ax.set_ylabel("validation sets")
    beside = f" (paper: {100 * paper:.3f}%)" if paper is not None else ""
    ax.set_title(f"{info['study']} emulator, {info['n']:,} validation sets: max {100 * info['max']:.3f}%{beside}, "
                 f"mean {100 * info['mean']:.3f}%", fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, figure)


def flow_marginals(samples: str, validation: str, figure: str) -> None:
    """The 16 output marginals of NN_f ``samples`` (red) against the ``validation`` outputs
    (blue), each over the data's 0.1-99.9% range widened by 10% (appendix C)."""
    y = read_outputs(validation)
    s = read_outputs(samples)
    fig, axes = subplots(2, 8, figsize=(20, 5))
    for j, (ax, name) in enumerate(zip(axes.flat, OUTPUT_NAMES)):
        lo, hi = np.percentile(y[:, j], [0.1, 99.9])
        pad = 0.1 * (hi - lo) if hi > lo else 1.0
        bins = np.linspace(lo - pad, hi + pad, 50)
        ax.hist(y[:, j], bins=bins, density=True, color="tab:blue", alpha=0.5, label="data")
        ax.hist(s[:, j], bins=bins, density=True, histtype="step", color="tab:red", lw=1.5, label="NN_f")
        ax.set_xlabel(label(name), fontsize=8)
        ax.set_yticks([])
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"Output marginals: {len(y):,} validation outputs (blue) vs {len(s):,} NN_f samples (red)")
    fig.tight_layout()
    save_figure(fig, figure)
