"""The EHR dataset of Harrod et al. (2021): download, validation, units, patient selection.

File layout (facts page): no header; 26 rows, one clinical feature each; column 0
is the feature name, columns 1..84 are patients 1..84; a missing value is ``none``.
The 16 model outputs are picked from 16 of the rows; LVEF is given in percent and
converted to a fraction; SVR and PVR are already in dyn·s/cm^5.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.data.downloads import download_checked
from cvsim6.registry import OUTPUT_NAMES
from cvsim6.table_files import write_table

log = logging.getLogger(__name__)

#: Feature names of the 26 rows, in file order.
EHR_FEATURES: tuple[str, ...] = (
    "heart_rate2", "systolic_bp_2", "diastolic_bp_2", "cardiac_output",
    "systemic_vascular_resistan", "pulmonary_vascular_resista", "cvp",
    "right_ventricle_diastole", "right_ventricle_systole", "rvedp", "aov_mean_pg",
    "aov_peak_pg", "mv_decel_time", "mv_e_a_ratio", "pv_at", "pv_max_pg", "ra_pressure",
    "ra_vol_a4c", "la_vol_a4c", "lv_esv", "lv_vol_a4c", "lvef", "lvot_max_flow",
    "pap_diastolic", "pap_systolic", "wedge_pressure",
)
#: Row of the file holding each model output, and the factor to the registry unit.
OUTPUT_ROWS: dict[str, tuple[int, float]] = {
    "Hr": (0, 1.0), "P_a_sys": (1, 1.0), "P_a_dia": (2, 1.0), "P_r_sys": (8, 1.0),
    "P_r_dia": (7, 1.0), "P_pa_sys": (24, 1.0), "P_pa_dia": (23, 1.0), "P_r_edp": (9, 1.0),
    "P_w": (25, 1.0), "P_cvp": (6, 1.0), "V_l_sys": (19, 1.0), "V_l_dia": (20, 1.0),
    "LVEF": (21, 0.01), "CO": (3, 1.0), "SVR": (4, 1.0), "PVR": (5, 1.0),
}
N_PATIENTS = 84
#: A patient is inverted when MORE than this many of the 16 outputs are present.
MIN_PRESENT_EXCLUSIVE = 10


class EHRFormatError(ValueError):
    """The EHR file does not have the expected layout; the message says where."""


def download_ehr(url: str, sha256: str, output: str) -> None:
    """Download the EHR CSV from its public origin and check its SHA-256 (setting ``ehr_data.sha256``)."""
    download_checked(url, sha256, output, what="ehr_data.sha256", local_key="ehr_data.path")


def read_ehr(path: str | Path) -> pd.DataFrame:
    """All 26 features of the file as floats (NaN = missing), index = patient 1..84.

    Raises :class:`EHRFormatError` naming the row, feature and patient of the first
    problem: wrong shape, unexpected feature name, a value neither a number nor ``none``.
    """
    raw = pd.read_csv(path, header=None, dtype=str, keep_default_na=False)
    if raw.shape != (len(EHR_FEATURES), N_PATIENTS + 1):
        raise EHRFormatError(
            f"{path}: expected {len(EHR_FEATURES)} rows x {N_PATIENTS + 1} columns "
            f"(feature name + {N_PATIENTS} patients), found {raw.shape[0]} x {raw.shape[1]}")
    values = np.empty((N_PATIENTS, len(EHR_FEATURES)))
    for i, expected in enumerate(EHR_FEATURES):
        name = raw.iat[i, 0].strip()
        if name != expected:
            raise EHRFormatError(f"{path}: row {i} is feature {name!r}, expected {expected!r}")
        for j in range(1, N_PATIENTS + 1):
            cell = raw.iat[i, j].strip()
            if cell.lower() == "none":
                values[j - 1, i] = np.nan
                continue
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
                ok = False
            else:
                ok = math.isfinite(v)
            if not ok:
                raise EHRFormatError(
                    f"{path}: row {i} ({expected}), patient {j}: value {cell!r} is neither a number nor 'none'")
            values[j - 1, i] = v
    return pd.DataFrame(values, columns=list(EHR_FEATURES), index=pd.RangeIndex(1, N_PATIENTS + 1, name="patient"))


def ehr_outputs(path: str | Path) -> pd.DataFrame:
    """The 16 model outputs of every patient in registry order and units (NaN = missing)."""
    raw = read_ehr(path)
    out = pd.DataFrame(index=raw.index)
    for name in OUTPUT_NAMES:
        row, factor = OUTPUT_ROWS[name]
        out[name] = raw[EHR_FEATURES[row]] * factor
    return out


def select_patients(outputs: pd.DataFrame, min_present_exclusive: int = MIN_PRESENT_EXCLUSIVE) -> pd.DataFrame:
    """Patients with more than ``min_present_exclusive`` of the 16 outputs present."""
    n = outputs[list(OUTPUT_NAMES)].notna().sum(axis=1)
    return outputs[n > min_present_exclusive]


def write_patient_selection(csv: str, patients: str, counts_csv: str, counts_md: str) -> None:
    """Select the patients to invert; write them (16 outputs, registry units) and a summary.

    ``patients`` (CSV): one row per selected patient with its outputs; ``md``: counts
    per output over the selected patients (the paper's 'Counts' column), CSV and Markdown.
    """
    out = ehr_outputs(csv)
    sel = select_patients(out)
    Path(patients).parent.mkdir(parents=True, exist_ok=True)
    sel.assign(n_present=sel.notna().sum(axis=1)).to_csv(patients)
    counts = pd.DataFrame({
        "Output": list(OUTPUT_NAMES),
        "Present (selected)": [f"{int(sel[c].notna().sum())}/{len(sel)}" for c in OUTPUT_NAMES],
        "Present (all)": [f"{int(out[c].notna().sum())}/{len(out)}" for c in OUTPUT_NAMES],
    })
    write_table(counts, counts_csv, counts_md,
                caption=f"EHR patients with more than {MIN_PRESENT_EXCLUSIVE} of 16 outputs: "
                        f"{len(sel)} of {len(out)} (paper: 46).")
    log.info("%d of %d patients selected", len(sel), len(out))
