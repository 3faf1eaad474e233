"""Evaluation of trained networks: error statistics and the tables built on them."""
from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsim6.data import datasets
from cvsim6 import paper_values
from cvsim6.nets import load_model
from cvsim6.reporting.figures import label, save_figure
from cvsim6.registry import OUTPUT_NAMES, OUTPUTS
from cvsim6.reporting.tables import write_table

log = logging.getLogger(__name__)


def error_statistics(y_true: np.ndarray, y_pred: np.ndarray) -> pd.DataFrame:
    """Mean, max and std of the absolute error per output (rows, units of each output).

    A row with a non-finite error anywhere is left out of every statistic; how many were
    is counted (logged, and in ``attrs``: ``n_rows`` given, ``n_used``, ``n_nonfinite``,
    for the table's caption, see :func:`nonfinite_words`). NaN everywhere if none is left.
    """
    err = np.abs(np.asarray(y_pred, float) - np.asarray(y_true, float))
    ok = np.isfinite(err).all(axis=1)
    err = err[ok]
    n_bad = int((~ok).sum())
    if n_bad:
        log.warning("error statistics: %d of %d rows left out (a non-finite value)", n_bad, len(ok))
    if len(err):
        cols = {"mean": err.mean(0), "max": err.max(0), "std": err.std(0)}
    else:
        cols = {k: np.full(err.shape[1], np.nan) for k in ("mean", "max", "std")}
    stats = pd.DataFrame(cols, index=pd.Index(OUTPUT_NAMES, name="output"))
    stats.attrs.update(n_rows=int(len(ok)), n_used=int(ok.sum()), n_nonfinite=n_bad)
    return stats


def nonfinite_words(stats: pd.DataFrame) -> str:
    """Caption words for the rows :func:`error_statistics` left out, e.g.
    ``"; 3 rows with a non-finite value left out"`` ("" when none were)."""
    n = int(stats.attrs.get("n_nonfinite", 0))
    return f"; {n:,} row{'s' if n != 1 else ''} with a non-finite value left out" if n else ""


def error_table(stats: pd.DataFrame, paper: dict | None) -> pd.DataFrame:
    """Per-output statistics with units, and the paper's values beside ours if given."""
    df = pd.DataFrame({"Output": list(OUTPUT_NAMES), "Unit": [o.unit for o in OUTPUTS]})
    for k in ("mean", "max", "std"):
        df[f"{k.capitalize()} (ours)"] = stats[k].to_numpy()
        if paper is not None:
            df[f"{k.capitalize()} (paper)"] = paper[k]
    return df


def emulator_validation(model: str, validation: str, csv: str, md: str, study: str) -> None:
    """Appendix C table: absolute error of the emulator on the validation split."""
    emu = load_model(model)
    v, y = datasets.load_split(validation)
    stats = error_statistics(y, emu.predict(v))
    paper = paper_values.EMULATOR_VALIDATION_STRUCTURAL if study == "structural" else None
    write_table(error_table(stats, paper), csv, md,
                caption=f"Emulator absolute error on the {len(v):,} validation sets ({study} study"
                        f"{nonfinite_words(stats)})" + (", paper appendix C beside ours" if paper else ""))


def relative_l2_errors(y_true: np.ndarray, y_pred: np.ndarray) -> np.ndarray:
    """Per row ``||y_pred - y_true||_2 / ||y_true||_2`` (fraction)."""
    y_true = np.asarray(y_true, float)
    return np.linalg.norm(np.asarray(y_pred, float) - y_true, axis=1) / np.linalg.norm(y_true, axis=1)


def max_of_random_subsets(errors: np.ndarray, subset: int, resamples: int, seed: int = 0) -> np.ndarray:
    """The largest of ``subset`` errors drawn without replacement from ``errors`` (n,), for each of
    ``resamples`` independent draws (seeded): (resamples,). The spread of a "max over k draws"
    headline that comes from which k draws were taken (``subset`` >= n gives the overall max)."""
    e = np.asarray(errors, float)
    if e.ndim != 1 or not e.size:
        raise ValueError(f"errors must be a non-empty 1-D array, got shape {e.shape}")
    if int(subset) < 1 or int(resamples) < 1:
        raise ValueError(f"subset and resamples must be >= 1, got {subset!r}, {resamples!r}")
    k = min(int(subset), e.size)
    rng = np.random.default_rng(seed)
    return np.array([e[rng.choice(e.size, k, replace=False)].max() for _ in range(int(resamples))])


def emulator_l2_histogram(model: str, validation: str, figure: str, summary: str, study: str = "ehr") -> None:
    """Histogram of the emulator's relative l2 error on the validation split (the paper's
    figure for the EHR emulator, max 0.984%; no paper value for the structural study)."""
    import json

    import matplotlib.pyplot as plt

    v, y = datasets.load_split(validation)
    err = relative_l2_errors(y, load_model(model).predict(v))
    paper = paper_values.EHR_EMULATOR_MAX_REL_L2 if study == "ehr" else None
    info = {"study": study, "n": int(len(err)), "max": float(err.max()), "mean": float(err.mean()),
            "paper_max": paper}
    with open(summary, "w") as fh:
        json.dump(info, fh, indent=2)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.hist(100 * err, bins=60, color="#3b75af")
    ax.set_xlabel("relative l2 error of the emulator (%)")
    ax.set_ylabel("validation sets")
    beside = f" (paper: {100 * paper:.3f}%)" if paper is not None else ""
    ax.set_title(f"{study} emulator, {len(err):,} validation sets: max {100 * err.max():.3f}%{beside}, "
                 f"mean {100 * err.mean():.3f}%", fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, figure)


def flow_marginals(flow: str, validation: str, figure: str, n_samples: int, seed: int) -> None:
    """The 16 output marginals of NN_f samples (red) against the data (blue) (appendix C)."""
    import matplotlib.pyplot as plt
    import torch

    _, y = datasets.load_split(validation)
    s = load_model(flow).sample_physical(n_samples, generator=torch.Generator().manual_seed(seed))
    fig, axes = plt.subplots(2, 8, figsize=(20, 5))
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
    fig.suptitle(f"Output marginals: {len(y):,} validation outputs (blue) vs {n_samples:,} NN_f samples (red)")
    fig.tight_layout()
    save_figure(fig, figure)
