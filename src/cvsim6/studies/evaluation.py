"""Evaluation of trained networks: error statistics and the tables built on them, and the
data behind the evaluation figures (drawn by :mod:`cvsim6.reporting.evaluation_figures`)."""
from __future__ import annotations

import json
import logging

import numpy as np
import pandas as pd
import torch

from cvsim6.data import datasets
from cvsim6 import paper_values
from cvsim6.nets import load_model
from cvsim6.registry import OUTPUT_NAMES, OUTPUTS
from cvsim6.table_files import write_table

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


def emulator_l2_errors(model: str, validation: str, errors: str, summary: str, study: str = "ehr") -> None:
    """The emulator's relative l2 error on each validation set (``errors`` CSV, column
    ``rel_l2_error``, fraction, in the split's row order) and its max and mean beside the
    paper's max (``summary`` JSON; the paper's figure for the EHR emulator, max 0.984%; no
    paper value for the structural study)."""
    v, y = datasets.load_split(validation)
    err = relative_l2_errors(y, load_model(model).predict(v))
    paper = paper_values.EHR_EMULATOR_MAX_REL_L2 if study == "ehr" else None
    info = {"study": study, "n": int(len(err)), "max": float(err.max()), "mean": float(err.mean()),
            "paper_max": paper}
    with open(summary, "w") as fh:
        json.dump(info, fh, indent=2)
    pd.DataFrame({"rel_l2_error": err}).to_csv(errors, index=False)


def flow_samples(flow: str, samples: str, n_samples: int, seed: int) -> None:
    """``n_samples`` outputs drawn from NN_f (seeded), physical units, one column per output
    (Parquet with units), for the marginals figure (appendix C)."""
    s = load_model(flow).sample_physical(n_samples, generator=torch.Generator().manual_seed(seed))
    datasets.write_dataset(pd.DataFrame(np.asarray(s, float), columns=list(OUTPUT_NAMES)), samples)
