"""Loss curves of the trained networks, drawn from the per-epoch losses CSV that training writes.

A module of its own, imported by no training code: the workflow draws each figure in a rule of
its own, so a change here redraws the figures without retraining a network (a rule reruns when
a package module it imports changes, see :mod:`cvsim6.workflow.codegraph`). For the same reason
it imports no network or training module: the model file's ``info`` is read through
:mod:`cvsim6.model_files`, so a change of the networks' code redraws no loss figure.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.ticker import FormatStrFormatter, MaxNLocator

from cvsim6.model_files import read_info
from cvsim6.reporting.figures import subplots

#: y-axis label per kind of network (the file-name stem before ``_delta``).
LOSS_LABELS = {
    "emulator": "MSE (standardized outputs)",
    "flow": "negative log-likelihood (nats)",
    "encoder_decoder": "weighted total loss",
    "npe": "negative log-likelihood (nats)",
}


def plot_training_losses(losses: str, figure: str, network: str, study: str = "", model: str | None = None) -> dict:
    """Workflow step: draw ``losses`` (CSV of one network's training) into ``figure`` (PNG).
    ``network`` is the file stem, e.g. ``"emulator"``, ``"flow_delta0.5"``,
    ``"encoder_decoder_delta1"`` or ``"npe_delta2"``; it sets the title and the y label (an
    emulator CSV with ``train_mse`` columns was trained with a weighted loss, see
    :func:`emulator_loss_label`). ``model``, the trained network's ``.pt`` file, when given: a
    network trained with restarts (its ``info["restart"]``) gets its candidates marked (see
    :func:`plot_losses`), and an emulator's label names its loss weighting.
    Returns the ``title``, ``ylabel``, ``cut`` (:func:`plot_losses`' record of what the axes cut)
    and ``restart`` (the model's restart record, ``None`` without one) of the figure."""
    m = re.fullmatch(r"emulator|(flow|encoder_decoder|npe)_delta([0-9]+(?:\.[0-9]*)?)", network)
    if m is None:
        raise ValueError(f"network {network!r} is not emulator, flow_delta<d>, encoder_decoder_delta<d> or npe_delta<d>")
    kind, delta = m.groups() if m.group(1) else ("emulator", None)
    ylabel = LOSS_LABELS[kind]
    if kind == "emulator" and "train_mse" in pd.read_csv(losses, nrows=0).columns:
        ylabel = emulator_loss_label(read_info(model).get("hyper", {}) if model else {})
    where = ", ".join(x for x in (study, f"delta={float(delta):g}" if delta else "") if x)
    title = {"npe": "NPE"}.get(kind, kind) + (f" ({where})" if where else "")
    restart = restart_record(model) if model else None
    cut = plot_losses(losses, figure, title=title, ylabel=ylabel, restart=restart)
    return {"title": title, "ylabel": ylabel, "cut": cut, "restart": restart}


def emulator_loss_label(hyper: dict) -> str:
    """y label of a weighted emulator loss from its training hyperparameters (``variance_floor``,
    ``relative_weight``; see :mod:`cvsim6.training.loss_weights`); "weighted MSE" when neither is known."""
    words = []
    if hyper.get("variance_floor") is not None:
        words.append("output variances floored")
    if hyper.get("relative_weight", 0):
        words.append(f"rows weighted by 1/|y|² (a = {hyper['relative_weight']:g})")
    return "MSE, " + ", ".join(words) if words else "weighted MSE (standardized outputs)"


def restart_record(model: str | Path) -> dict | None:
    """The restart record a network trained with restarts keeps in its ``.pt`` file's ``info``
    (``epochs``: the epoch of the choice; ``chosen``: the candidate kept; ``seeds`` and
    ``test_loss``: per candidate, ``inf`` for one that diverged; with a ``target``, each candidate's
    ``worst_reconstruction`` MSE), ``None`` without restarts."""
    return read_info(model).get("restart")


def _mark_restart(ax, restart: dict) -> None:
    """The candidates' test losses at the epoch of the choice: the kept one filled, the others
    hollow, a dashed line at that epoch; the legend names the choice and any diverged candidate."""
    r, chosen = int(restart["epochs"]), int(restart["chosen"])
    scores = np.asarray(restart["test_loss"], dtype=float)
    ax.axvline(r, color="0.4", ls="--", lw=1.0, zorder=0)
    others = [c for c in range(scores.size) if c != chosen and np.isfinite(scores[c])]
    diverged = [c for c in range(scores.size) if not np.isfinite(scores[c])]
    ax.plot([r] * len(others), scores[others], ls="none", marker="o", ms=7, mfc="none", mec="black",
            label=f"other initializations at epoch {r} ({len(others)})"
                  + (f"; {len(diverged)} diverged" if diverged else ""))
    target, worst = restart.get("target"), restart.get("worst_reconstruction") or []
    met = [c for c, w in enumerate(worst) if target is not None and w is not None and w <= target]
    kept = (f"kept: best test loss at epoch {r} of the {len(met)} of {scores.size}\nwith every parameter "
            f"reconstructed (MSE <= {target:g})" if chosen in met else f"kept: best test loss of {scores.size} at epoch {r}")
    ax.plot([r], [scores[chosen]], ls="none", marker="o", ms=7, color="black", label=kept)


def _log_axis(ax, values: np.ndarray) -> None:
    """Log-scale y; plain numbers on the ticks when the data span less than a decade."""
    ax.set_yscale("log")
    if values.max() / values.min() < 10.0:
        ax.yaxis.set_major_formatter(FormatStrFormatter("%.3g"))
        ax.yaxis.set_minor_formatter(FormatStrFormatter("%.3g"))


def divergence_epochs(values, decades: float = 2.0) -> np.ndarray:
    """Mask of a positive loss series' entries more than ``decades`` decades above the lowest
    value seen so far: a divergence spike and its recovery, not the start of training (a loss
    that only falls is never flagged). NaNs (epochs without a test pass) are never flagged."""
    v = np.asarray(values, dtype=float)
    finite = np.isfinite(v)
    if not finite.any() or (v[finite] <= 0).any():
        return np.zeros(v.shape, dtype=bool)
    running_min = np.fmin.accumulate(np.where(finite, v, np.nan))
    return finite & (v > running_min * 10.0**decades)


def _set_limits(ax, values: np.ndarray, healthy: np.ndarray) -> float | None:
    """Y limits from the ``healthy`` entries of ``values`` (rows x series), log scale when all
    are positive (linear otherwise, cut at the 98th percentile). Returns the axis top when some
    value lies above it, so the caller can mark the cut; ``None`` when nothing is hidden."""
    finite = np.isfinite(values)
    shown = values[finite & healthy[:, None]]
    if not shown.size:
        return None
    everything = values[finite]
    if (everything > 0).all():
        _log_axis(ax, shown)
        pad = 10.0 ** (0.04 * max(np.log10(shown.max() / shown.min()), 0.05))  # 4% of the span each side
        lo, hi = shown.min() / pad, shown.max() * pad
    else:
        lo, hi = np.quantile(shown, [0.0, 0.98])
        pad = 0.05 * (hi - lo if hi > lo else 1.0)
        lo, hi = lo - pad, hi + pad
    ax.set_ylim(lo, hi)
    return hi if (everything > hi).any() else None


def cut_label(cut_epochs: np.ndarray, peak: float) -> str:
    """The red note of a loss figure: which epochs ran off the top of the axis, and how high."""
    if len(cut_epochs) == 1:
        return f"epoch {int(cut_epochs[0])} above the axis (peak {peak:.2g})"
    return (f"{len(cut_epochs)} epochs above the axis (epochs {int(np.min(cut_epochs))}-{int(np.max(cut_epochs))}, "
            f"peak {peak:.2g})")


def _mark_cut(ax, epochs: np.ndarray, values: np.ndarray, top: float) -> dict:
    """Shade the epochs whose values run off the top of the axis, draw them as triangles on the
    top edge and say how many there were and how high they went."""
    above = (np.nan_to_num(values, nan=-np.inf) > top).any(axis=1)
    cut = epochs[above]
    for start, stop in _runs(cut):
        ax.axvspan(start - 0.5, stop + 0.5, color="red", alpha=0.12, lw=0)
    ax.plot(cut, np.full(cut.shape, top), ls="none", marker="^", ms=4, color="red", clip_on=False)
    peak = float(np.nanmax(values[above]))
    ax.text(0.99, 0.97, cut_label(cut, peak),
            transform=ax.transAxes, ha="right", va="top", fontsize="small", color="red",
            bbox=dict(facecolor="white", edgecolor="none", alpha=0.8))
    return {"top": float(top), "epochs": cut.tolist(), "peak": peak}


def _runs(epochs: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs (first, last) of a sorted integer epoch array."""
    if not epochs.size:
        return []
    breaks = np.flatnonzero(np.diff(epochs) > 1)
    starts = np.r_[epochs[0], epochs[breaks + 1]]
    stops = np.r_[epochs[breaks], epochs[-1]]
    return list(zip(starts.tolist(), stops.tolist()))


def plot_losses(losses_csv: str | Path, figure: str | Path, title: str = "", ylabel: str = "loss",
                restart: dict | None = None) -> dict:
    """PNG loss curve from a losses CSV: train and test, log-scale y (linear when a loss is
    not positive, e.g. a flow NLL); encoder/decoder CSVs get a second panel per loss term.

    A divergence spike (train or test loss more than two decades above its lowest value so far,
    see :func:`divergence_epochs`) would flatten the rest of the curve on a log axis, so the axes
    are scaled to the other epochs and the cut is marked: the spike's epochs are shaded, its
    points sit as red triangles on the top edge, and a label gives their count and peak.
    Epochs in which training skipped a step (a non-finite gradient norm, column ``skipped_steps``
    of a run with ``grad_clip``) get a dotted vertical line. ``restart`` (:func:`restart_record`)
    marks the best-of-k choice: every candidate's test loss at that epoch (the curves are the
    kept candidate's), kept in view by the y limits.
    Returns, per panel, the axis top and the epochs cut (``{}`` when nothing was cut), and under
    ``"skipped"`` the epochs with a skipped step, when there are any."""
    df = pd.read_csv(losses_csv)
    epochs = df["epoch"].to_numpy()
    parts = [c[len("train_"):] for c in df.columns if c.startswith("train_") and c != "train_loss"]
    healthy = ~(divergence_epochs(df["train_loss"]) | divergence_epochs(df["test_loss"]))
    cuts = {}
    fig, axes = subplots(1, 2 if parts else 1, figsize=(12 if parts else 7, 4.5), squeeze=False)
    ax = axes[0, 0]
    ax.plot(epochs, df["train_loss"], label="train", lw=1.2)
    tested = df[np.isfinite(df["test_loss"])]
    ax.plot(tested["epoch"], tested["test_loss"], label="test", lw=1.2, marker="." if len(tested) < 50 else None)
    loss_values = df[["train_loss", "test_loss"]].to_numpy(dtype=float)
    if restart is not None:
        _mark_restart(ax, restart)
        scores = np.asarray(restart["test_loss"], dtype=float)
        scores = scores[np.isfinite(scores)]
        # the candidates' scores take part in the limits (as extra healthy rows), not in the cut marks
        top = _set_limits(ax, np.vstack([loss_values, np.c_[scores, scores]]),
                          np.r_[healthy, np.ones(scores.size, dtype=bool)])
    else:
        top = _set_limits(ax, loss_values, healthy)
    if top is not None:
        cuts["loss"] = _mark_cut(ax, epochs, loss_values, top)
    has_skips = df["skipped_steps"] > 0 if "skipped_steps" in df else None
    if has_skips is not None and has_skips.any():
        skipped = df.loc[has_skips, "epoch"].astype(int).tolist()
        for k, e in enumerate(skipped):
            ax.axvline(e, color="0.35", ls=":", lw=1.0, zorder=0,
                       label=f"skipped step (non-finite gradient): {int(df['skipped_steps'].sum())} in "
                             f"{len(skipped)} epoch{'s' if len(skipped) > 1 else ''}" if k == 0 else None)
        cuts["skipped"] = skipped
    ax.set_xlabel("epoch")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel(ylabel)
    ax.set_title(title or "loss")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if parts:
        ax2 = axes[0, 1]
        for i, p in enumerate(parts):
            color = f"C{i}"
            ax2.plot(epochs, df[f"train_{p}"], color=color, lw=1.2, label=f"{p} (train)")
            ax2.plot(tested["epoch"], tested[f"test_{p}"], color=color, lw=1.2, ls="--", label=f"{p} (test)")
        term_values = df[[f"train_{p}" for p in parts] + [f"test_{p}" for p in parts]].to_numpy(dtype=float)
        top = _set_limits(ax2, term_values, healthy)
        if top is not None:
            cuts["terms"] = _mark_cut(ax2, epochs, term_values, top)
        ax2.set_xlabel("epoch")
        ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax2.set_ylabel("unweighted term")
        ax2.set_title("loss terms")
        ax2.grid(True, which="both", alpha=0.3)
        ax2.legend(fontsize="small")
    fig.tight_layout()
    Path(figure).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=150)
    return cuts
