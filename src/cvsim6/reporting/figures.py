"""Shared plotting helpers: one style, labels with units from the registry."""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from cvsim6.registry import OUTPUT_BY_NAME, PARAMETER_BY_NAME  # noqa: E402


def label(name: str) -> str:
    """Axis label ``'name (unit)'`` for a parameter or output name."""
    item = OUTPUT_BY_NAME.get(name) or PARAMETER_BY_NAME.get(name)
    if item is None or item.unit == "-":
        return name
    return f"{name} ({item.unit})"


def save_figure(fig, path: str | Path, dpi: int = 150) -> None:
    """Save ``fig`` as PNG at ``path`` and as PDF beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    if path.suffix.lower() != ".pdf":
        fig.savefig(path.with_suffix(".pdf"), bbox_inches="tight")
    plt.close(fig)


def histogram_grid(df, columns: Sequence[str], path: str | Path, title: str = "", bins: int = 50,
                   ncols: int = 4) -> None:
    """A grid of histograms, one per column of ``df``, labelled with units."""
    n = len(columns)
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, 2.4 * nrows), squeeze=False)
    for ax, col in zip(axes.flat, columns):
        ax.hist(df[col].to_numpy(), bins=bins, color="#3b75af", alpha=0.85)
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
