"""Shared plotting helpers: one style, labels with units from the registry.

Figures are :class:`matplotlib.figure.Figure` objects made by :func:`subplots`, outside
pyplot: no backend is chosen and no global state is touched, at import or when drawing
(saving a PNG or PDF renders with matplotlib's Agg or PDF canvas, display or not).
"""
from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from cvsim6.registry import OUTPUT_BY_NAME, PARAMETER_BY_NAME


def label(name: str) -> str:
    """Axis label ``'name (unit)'`` for a parameter or output name."""
    item = OUTPUT_BY_NAME.get(name) or PARAMETER_BY_NAME.get(name)
    if item is None or item.unit == "-":
        return name
    return f"{name} ({item.unit})"


def subplots(nrows: int = 1, ncols: int = 1, figsize: tuple[float, float] | None = None, **kwargs):
    """``(figure, axes)`` like ``pyplot.subplots`` (``figsize`` in inches; ``sharex``, ``squeeze``,
    ``subplot_kw`` ... passed on to :meth:`Figure.subplots`), but a figure pyplot does not manage."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def close(fig) -> None:
    """Free ``fig``: a pyplot figure is closed; one from :func:`subplots` needs nothing."""
    if fig.canvas.manager is not None:
        import matplotlib.pyplot as plt

        plt.close(fig)


def save_figure(fig, path: str | Path, dpi: int = 150) -> None:
    """Save ``fig`` as PNG at ``path`` (``dpi`` dots per inch) and as PDF beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    if path.suffix.lower() != ".pdf":
        fig.savefig(path.with_suffix(".pdf"), bbox_inches="tight")
    close(fig)
