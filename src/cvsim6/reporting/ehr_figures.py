"""Figures of the EHR study (paper section 3.4), drawn from the files its steps write: the
selected patients (CSV, index ``patient``, the 16 outputs in registry units, NaN = not measured)
and one noise level's predictions (Parquet from :func:`cvsim6.studies.ehr.invert_ehr_patients`:
``id``, ``noise_level``, and the emulated outputs ``pred_<name>`` per latent draw).
Reads no network and runs no inversion.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from cvsim6.registry import OUTPUT_NAMES, noise_std
from cvsim6.reporting.figures import label, save_figure, subplots

#: Prefix of the emulated-output columns of a predictions file (``cvsim6.studies.ehr.PRED``).
PRED = "pred_"


def read_predictions(predictions: str) -> pd.DataFrame:
    """The columns of a predictions Parquet the figures need: ``id``, ``noise_level`` and
    the 16 ``pred_<name>`` columns (registry units), one row per patient and latent draw."""
    return pd.read_parquet(predictions, columns=["id", "noise_level", *(PRED + n for n in OUTPUT_NAMES)])


def ehr_patient_figure(patients: str, predictions: str, figure: str) -> None:
    """Workflow step: per output, each patient's measurement (red star), the predictions of the
    latent draws (blue dots) and the measurement +- 3 noise standard deviations (gray); outputs no
    patient has are left out. PNG at ``figure``, PDF beside it."""
    obs = pd.read_csv(patients, index_col="patient")
    pred = read_predictions(predictions)
    d = float(pred["noise_level"].iloc[0])
    names = [n for n in OUTPUT_NAMES if obs[n].notna().any()]
    ncols = 2
    nrows = -(-len(names) // ncols)
    fig, axes = subplots(nrows, ncols, figsize=(14, 2.3 * nrows), squeeze=False)
    s = dict(zip(OUTPUT_NAMES, noise_std()))
    for ax, name in zip(axes.flat, names):
        o = obs[name].dropna()
        x = np.arange(len(o))
        ax.bar(x, 6 * s[name], bottom=o.to_numpy() - 3 * s[name], width=0.8, color="0.85",
               label="measurement ± 3σ")
        for xi, pid in zip(x, o.index):
            p = pred.loc[pred["id"] == pid, PRED + name].to_numpy()
            ax.plot(np.full(len(p), xi), p, ".", color="tab:blue", ms=2, alpha=0.5)
        ax.plot(x, o.to_numpy(), "*", color="tab:red", ms=7, label="EHR measurement")
        ax.set_xticks(x)
        ax.set_xticklabels([str(p) for p in o.index], fontsize=6, rotation=90)
        ax.set_ylabel(label(name), fontsize=9)
        ax.set_xlim(-1, len(o))
    for ax in list(axes.flat)[len(names):]:
        ax.set_visible(False)
    axes.flat[0].plot([], [], ".", color="tab:blue", ms=8, label="predictions (latent draws)")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.supxlabel("patient")
    fig.suptitle(f"Patient-specific predictions, delta = {d:g} (V_l_sys never measured: omitted)", y=0.995)
    fig.tight_layout(rect=(0, 0, 1, 0.975))
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.985), ncols=3, fontsize=9,
               frameon=False)
    save_figure(fig, figure)
