"""The EHR patients inverted three ways, as workflow steps: e_k (paper table 5) for

1. inVAErt, decoded sets through the emulator NN_e (the paper's way: ``pred_`` columns of
   the inVAErt predictions, :func:`cvsim6.studies.ehr.invert_ehr_patients`);
2. inVAErt, decoded sets through the exact simulator (batch path);
3. NPE, posterior samples through the simulator.

NPE inverts the same completed output vector as inVAErt (Algorithm 1's most likely
completion under NN_f, the ``completed_`` columns of the inVAErt predictions), with as many
samples per patient as inVAErt's latent draws. Sets the simulator flags (outside the
model's domain, unphysical, failed) have no simulated outputs and are left out of e_k;
their counts are reported. Units: registry units.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from cvsim6 import paper_values
from cvsim6.model import solver
from cvsim6.studies.ehr import PRED, error_per_output
from cvsim6.inference.npe import load_npe
from cvsim6.registry import OUTPUT_NAMES, OUTPUTS, PARAMETER_NAMES
from cvsim6.table_files import write_table

log = logging.getLogger(__name__)

#: The three ways, in table order: (column label, file role).
WAYS = ("inVAErt via emulator", "inVAErt via simulator", "NPE via simulator")


def _simulate_rows(df: pd.DataFrame, simulator: dict) -> pd.DataFrame:
    """``df`` with its ``pred_`` columns replaced by simulator outputs of its parameter columns
    (NaN where the simulator flags a set) and ``sim_status`` (solver status code)."""
    out = df.copy()
    ok = out["status"].eq("ok").to_numpy()
    y = np.full((len(out), len(OUTPUT_NAMES)), np.nan)
    st = np.full(len(out), -1, dtype=np.int64)
    if ok.any():
        sim, status = solver.simulate_batch(out.loc[ok, list(PARAMETER_NAMES)].to_numpy(float),
                                            steps_per_cycle=simulator["steps_per_cycle"],
                                            n_cycles=simulator["n_cycles"], window_cycles=simulator["window_cycles"],
                                            invalid="flag")
        sim[status != 0] = np.nan
        y[ok], st[ok] = sim, status
    for j, name in enumerate(OUTPUT_NAMES):
        out[PRED + name] = y[:, j]
    out["sim_status"] = st
    return out


def simulate_ehr_predictions(predictions: str, simulated: str, simulator: dict) -> None:
    """Workflow step: the inVAErt predictions of one noise level with simulated outputs."""
    df = _simulate_rows(pd.read_parquet(predictions), simulator)
    Path(simulated).parent.mkdir(parents=True, exist_ok=True)
    df.to_parquet(simulated, index=False)
    st = df.loc[df["status"] == "ok", "sim_status"]
    log.info("%d decoded sets simulated, %d flagged (%s)", len(st), int((st != 0).sum()),
             dict(st[st != 0].value_counts()))


def invert_ehr_npe(predictions: str, npe: str, npe_predictions: str, simulator: dict, seed: int,
                   threads: int = 1) -> None:
    """Workflow step: NPE samples for every patient inVAErt inverted (its completed outputs),
    as many per patient as inVAErt's draws, with simulated outputs in the ``pred_`` columns."""
    torch.set_num_threads(int(threads))
    inv = pd.read_parquet(predictions)
    post = load_npe(npe)
    ok = inv[inv["status"] == "ok"]
    first = ok.groupby("id", sort=False).first()
    n = int(ok.groupby("id", sort=False).size().max()) if len(ok) else 0
    rows = []
    if len(first):
        y = first[["completed_" + c for c in OUTPUT_NAMES]].to_numpy(float)
        v = post.sample(y, n, seed=seed)  # (patients, n, 23)
        for k, pid in enumerate(first.index):
            df = pd.DataFrame(v[k], columns=list(PARAMETER_NAMES))
            df.insert(0, "draw", np.arange(n))
            df.insert(0, "status", "ok")
            df.insert(0, "noise_level", float(inv["noise_level"].iloc[0]))
            df.insert(0, "id", pid)
            for c in OUTPUT_NAMES:
                df["completed_" + c] = first.at[pid, "completed_" + c]
            rows.append(df)
    skipped = inv.loc[inv["status"] != "ok", ["id", "noise_level", "status"]]
    out = pd.concat(rows + [skipped], ignore_index=True) if rows else skipped.copy()
    out = _simulate_rows(out, simulator)
    Path(npe_predictions).parent.mkdir(parents=True, exist_ok=True)
    out.to_parquet(npe_predictions, index=False)
    log.info("NPE: %d patients x %d samples; %d not inverted by inVAErt, kept as such", len(first), n, len(skipped))


def ehr_error_methods(patients: str, emulated: list[str], invaert_simulated: list[str], npe_simulated: list[str],
                      csv: str, md: str, figure_noise_level: float) -> None:
    """Workflow step: e_k per output for the three ways and every noise level, the paper's
    e_k at delta = 0.5 beside, and the way with the lowest e_k at ``figure_noise_level``."""
    obs = pd.read_csv(patients, index_col="patient")
    table = pd.DataFrame({"Output": list(OUTPUT_NAMES), "Unit": [o.unit for o in OUTPUTS]})
    flagged = {}
    fig_cols = []
    for paths, way in zip((emulated, invaert_simulated, npe_simulated), WAYS):
        for path in paths:
            pred = pd.read_parquet(path)
            d = float(pred["noise_level"].iloc[0])
            col = f"{way}, delta={d:g}"
            table[col] = error_per_output(obs, pred)["e_k"].to_numpy()
            if "sim_status" in pred:
                st = pred.loc[pred["status"] == "ok", "sim_status"]
                flagged[col] = f"{int((st != 0).sum())}/{len(st)}"
            if d == float(figure_noise_level):
                fig_cols.append(col)
    if fig_cols:
        vals = table[fig_cols].to_numpy(float)
        table[f"Lowest at delta={float(figure_noise_level):g}"] = [
            fig_cols[int(np.nanargmin(r))].split(",")[0] if np.isfinite(r).any() else "" for r in vals]
    i = paper_values.EHR_DELTAS.index(0.5)
    table["paper delta=0.5"] = [paper_values.EHR_EK[n][i] for n in OUTPUT_NAMES]
    e = error_per_output(obs, pd.read_parquet(emulated[0]))
    table["Counts"] = [f"{c}/{n}" for c, n in zip(e["count"], e["patients"])]
    note = "; ".join(f"{k}: {v}" for k, v in flagged.items())
    write_table(table, csv, md, caption="Reconstruction error e_k per output, three ways: inVAErt's decoded sets "
                                        "through the emulator (the paper's table 5), the same sets through the "
                                        "simulator, and NPE posterior samples through the simulator. Sets the "
                                        f"simulator flags are left out (flagged/total: {note or 'none'})")
