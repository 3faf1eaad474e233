"""Inverting real patients (paper section 3.4) and new ones (the ``cvsim6 invert`` CLI).

Per observation (16 outputs, NaN = missing): Algorithm 1 keeps the most likely
completion under NN_f, N_w latent draws are decoded by NN_d into parameter sets, and
the noise-free emulator NN_e maps them back to outputs. Each observation also gets
an out-of-distribution percentile (:mod:`cvsim6.inversion`).

The error of output k at noise level delta is (paper eq. 9)
``e_k = mean over patients with y_k observed of mean_i |y_k - Y_ik|``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from . import inversion
from .registry import OUTPUT_NAMES, OUTPUTS, PARAMETER_NAMES, noise_std

log = logging.getLogger(__name__)

#: Paper table 5 (e_k per output, delta = 0.25, 0.5, 1.0, 2.0; None where never observed).
PAPER_EK = {
    "Hr": (0.602, 0.440, 0.843, 2.636), "P_a_sys": (5.204, 2.284, 3.379, 2.738),
    "P_a_dia": (3.614, 1.605, 2.045, 2.627), "P_r_sys": (1.669, 1.323, 1.469, 1.476),
    "P_r_dia": (1.170, 1.684, 2.022, 3.383), "P_pa_sys": (1.907, 1.227, 1.606, 1.386),
    "P_pa_dia": (1.285, 1.062, 1.065, 1.290), "P_r_edp": (0.540, 0.599, 0.786, 2.787),
    "P_w": (0.887, 0.740, 1.258, 1.200), "P_cvp": (1.194, 0.371, 0.733, 0.821),
    "V_l_sys": (None, None, None, None), "V_l_dia": (50.960, 47.391, 103.402, 119.440),
    "LVEF": (0.012, 0.008, 0.015, 0.024), "CO": (0.200, 0.121, 0.281, 0.274),
    "SVR": (28.755, 24.728, 25.896, 41.233), "PVR": (1.924, 1.812, 2.010, 3.795),
}
PAPER_DELTAS = (0.25, 0.5, 1.0, 2.0)
PRED = "pred_"  # prefix of emulated-output columns (Hr is both a parameter and an output)


def invert_observations(observations: pd.DataFrame, flow, encdec, emulator, n_latent: int = 100,
                        n_flow_samples: int = 200_000, seed: int = 0,
                        reference_outputs: np.ndarray | None = None, n_reference: int = 100,
                        reference_flow_samples: int = 4096, progress: bool = False,
                        corrector_steps: int = 0) -> pd.DataFrame:
    """Invert each row of ``observations`` (any subset of the 16 output columns, NaN = missing).

    Returns a long table: one row per observation and latent draw with ``id`` (the
    observation's index), ``draw``, the 23 parameters, the 16 emulated outputs
    (``pred_<name>``), the completion used (``completed_<name>``), ``log_density`` of
    that completion and ``ood_percentile`` (NaN without ``reference_outputs``).
    ``corrector_steps``: predictor-corrector rounds of :func:`cvsim6.inversion.decode_latent`.
    """
    unknown = [c for c in observations.columns if c not in OUTPUT_NAMES]
    if unknown:
        raise ValueError(f"unknown output column(s) {unknown}; expected any of {list(OUTPUT_NAMES)}")
    obs = observations.reindex(columns=list(OUTPUT_NAMES)).astype(float)
    rows = []
    it = obs.iterrows()
    if progress:
        from tqdm import tqdm

        it = tqdm(it, total=len(obs), unit="patient", desc="invert")
    ref_rng = np.random.default_rng(seed)
    for k, (pid, y) in enumerate(it):
        y = y.to_numpy()
        if not np.isfinite(y).any():
            raise ValueError(f"observation {pid!r}: no output given")
        best, lp = inversion.complete_missing(flow, y, n_flow_samples, top_k=1, seed=seed + 7919 * k)
        v = inversion.decode_latent(encdec, best, n_latent, seed=seed + 104729 * k,
                                    corrector_steps=corrector_steps)[0]
        yhat = np.asarray(emulator.predict(v))
        pct = np.nan
        if reference_outputs is not None:
            ref = np.asarray(reference_outputs, float)
            pick = ref[ref_rng.choice(len(ref), size=min(n_reference, len(ref)), replace=False)]
            scores = inversion.reference_scores(flow, pick, ~np.isfinite(y), reference_flow_samples, seed=seed + k)
            pct = inversion.ood_percentile(lp[0], scores)
        df = pd.DataFrame(v, columns=list(PARAMETER_NAMES))
        df.insert(0, "draw", np.arange(n_latent))
        df.insert(0, "id", pid)
        for j, name in enumerate(OUTPUT_NAMES):
            df[PRED + name] = yhat[:, j]
        for j, name in enumerate(OUTPUT_NAMES):
            df["completed_" + name] = best[0, j]
        df["log_density"] = lp[0]
        df["ood_percentile"] = pct
        rows.append(df)
    return pd.concat(rows, ignore_index=True)


def invert_ehr_patients(patients: str, flow: str, encoder_decoder: str, emulator: str, reference: str,
                        predictions: str, noise_level: float, n_latent: int, n_flow_samples: int,
                        n_reference: int, reference_flow_samples: int, seed: int,
                        corrector_steps: int = 0) -> None:
    """Workflow step: invert the selected EHR patients with the networks of one noise level."""
    from .datasets import load_split
    from .networks import load_model

    obs = pd.read_csv(patients, index_col="patient")[list(OUTPUT_NAMES)]
    _, y_ref = load_split(reference)
    df = invert_observations(obs, load_model(flow), load_model(encoder_decoder), load_model(emulator),
                             n_latent=n_latent, n_flow_samples=n_flow_samples, seed=seed,
                             reference_outputs=y_ref, n_reference=n_reference,
                             reference_flow_samples=reference_flow_samples, progress=True,
                             corrector_steps=corrector_steps)
    df.insert(1, "noise_level", float(noise_level))
    Path(predictions).parent.mkdir(parents=True, exist_ok=True)
    df.to_parquet(predictions, index=False)
    log.info("delta=%g: %d patients inverted", noise_level, df["id"].nunique())


def error_per_output(observations: pd.DataFrame, predictions: pd.DataFrame) -> pd.DataFrame:
    """e_k and counts per output: mean over observed patients of mean_i |y_k - Y_ik|."""
    rows = []
    for name in OUTPUT_NAMES:
        obs = observations[name].dropna()
        errs = []
        for pid, yk in obs.items():
            pred = predictions.loc[predictions["id"] == pid, PRED + name].to_numpy()
            errs.append(np.abs(yk - pred).mean())
        rows.append({"output": name, "e_k": float(np.mean(errs)) if errs else np.nan,
                     "count": len(obs), "patients": len(observations)})
    return pd.DataFrame(rows).set_index("output")


def ehr_error_table(patients: str, predictions: list[str], csv: str, md: str) -> None:
    """The paper's table 5: e_k per output and noise level, counts, the paper's values beside."""
    from .tables import write_table

    obs = pd.read_csv(patients, index_col="patient")
    table = pd.DataFrame({"Output": list(OUTPUT_NAMES), "Unit": [o.unit for o in OUTPUTS]})
    deltas = []
    for path in predictions:
        pred = pd.read_parquet(path)
        d = float(pred["noise_level"].iloc[0])
        deltas.append(d)
        table[f"delta={d:g}"] = error_per_output(obs, pred)["e_k"].to_numpy()
    cols = [f"delta={d:g}" for d in deltas]
    table["Best (ours)"] = [cols[int(np.nanargmin(r))] if np.isfinite(r).any() else "" for r in table[cols].to_numpy()]
    for i, d in enumerate(PAPER_DELTAS):
        table[f"paper delta={d:g}"] = [PAPER_EK[n][i] for n in OUTPUT_NAMES]
    e = error_per_output(obs, pd.read_parquet(predictions[0]))
    table["Counts"] = [f"{c}/{n}" for c, n in zip(e["count"], e["patients"])]
    write_table(table, csv, md, caption="Reconstruction error e_k per output (N_w latent draws, emulated), "
                                        "EHR patients with more than 10 outputs; paper table 5 beside")


def ehr_patient_figure(patients: str, predictions: str, figure: str) -> None:
    """Per output: each patient's measurement (red star), the predictions (blue dots), +-3 sigma (gray)."""
    import matplotlib.pyplot as plt

    from .plots import label, save_figure

    obs = pd.read_csv(patients, index_col="patient")
    pred = pd.read_parquet(predictions)
    d = float(pred["noise_level"].iloc[0])
    names = [n for n in OUTPUT_NAMES if obs[n].notna().any()]
    ncols = 2
    nrows = -(-len(names) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(14, 2.3 * nrows), squeeze=False)
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


def ood_table(predictions: str, csv: str, md: str) -> None:
    """Per patient: log-density of the best completion and its OOD percentile."""
    from .tables import write_table

    pred = pd.read_parquet(predictions)
    per = pred.groupby("id")[["log_density", "ood_percentile"]].first().reset_index()
    per["flag (< 1st percentile)"] = per["ood_percentile"] < 1.0
    write_table(per.rename(columns={"id": "patient"}), csv, md,
                caption="Out-of-distribution score per patient: percentile of the flow log-density of "
                        "its best completion among simulated outputs with the same entries missing")
