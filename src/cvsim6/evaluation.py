"""Evaluation of trained networks: error statistics and the tables built on them."""
from __future__ import annotations

import numpy as np
import pandas as pd

from . import datasets, paper_values
from .registry import OUTPUT_NAMES, OUTPUTS


def error_statistics(y_true: np.ndarray, y_pred: np.ndarray) -> pd.DataFrame:
    """Mean, max and std of the absolute error per output (rows), NaN rows ignored."""
    err = np.abs(np.asarray(y_pred, float) - np.asarray(y_true, float))
    ok = np.isfinite(err).all(axis=1)
    err = err[ok]
    return pd.DataFrame({"mean": err.mean(0), "max": err.max(0), "std": err.std(0)},
                        index=pd.Index(OUTPUT_NAMES, name="output"))


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
    from .networks import load_model
    from .tables import write_table

    emu = load_model(model)
    v, y = datasets.load_split(validation)
    stats = error_statistics(y, emu.predict(v))
    paper = paper_values.EMULATOR_VALIDATION_STRUCTURAL if study == "structural" else None
    write_table(error_table(stats, paper), csv, md,
                caption=f"Emulator absolute error on the {len(v):,} validation sets ({study} study)"
                        + (", paper appendix C beside ours" if paper else ""))
