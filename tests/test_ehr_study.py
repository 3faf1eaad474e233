"""The EHR error criterion e_k and the EHR stage end to end (smoke config)."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cvsim6 import ehr_study, registry
from test_workflow import copy_workflow, snakemake

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "EHR_dataset.csv"


def test_error_per_output_is_the_papers_criterion():
    names = registry.OUTPUT_NAMES
    obs = pd.DataFrame(np.nan, index=pd.Index([1, 2], name="patient"), columns=list(names))
    obs.loc[1, "Hr"], obs.loc[2, "Hr"] = 60.0, 80.0
    obs.loc[2, "CO"] = 5.0
    pred = pd.DataFrame({"id": [1, 1, 2, 2], "draw": [0, 1, 0, 1]})
    for n in names:
        pred[ehr_study.PRED + n] = 0.0
    pred[ehr_study.PRED + "Hr"] = [61.0, 63.0, 80.0, 79.0]  # |err| means: 2.0 and 0.5
    pred[ehr_study.PRED + "CO"] = [9.0, 9.0, 4.0, 6.0]  # only patient 2 observed: 1.0
    e = ehr_study.error_per_output(obs, pred)
    assert e.loc["Hr", "e_k"] == pytest.approx(1.25) and e.loc["Hr", "count"] == 2
    assert e.loc["CO", "e_k"] == pytest.approx(1.0) and e.loc["CO", "count"] == 1
    assert np.isnan(e.loc["V_l_sys", "e_k"]) and e.loc["V_l_sys", "count"] == 0


@pytest.mark.skipif(not REAL.is_file(), reason="local copy of the EHR data not present")
def test_ehr_stage_end_to_end(tmp_path):
    work = copy_workflow(tmp_path)
    targets = ["results/tables/ehr_error_per_output.md", "results/ehr/patient_predictions_delta0.5.png",
               "results/tables/ehr_ood_delta0.5.md"]
    proc = snakemake("--cores", "2", *targets, "--configfile", "config/smoke.yaml",
                     "--config", f"ehr_data={{'path': '{REAL}'}}", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = pd.read_csv(work / "results/tables/ehr_error_per_output.csv").set_index("Output")
    assert list(table["Counts"]) == [f"{c}/46" for c in (46, 46, 46, 44, 11, 46, 46, 44, 46, 3, 0, 3, 45, 46, 46, 46)]
    assert {"delta=0.5", "delta=2", "paper delta=0.5"} <= set(table.columns)
    assert np.isnan(table.loc["V_l_sys", "delta=0.5"])
    pred = pd.read_parquet(work / "results/ehr/predictions_delta0.5.parquet")
    assert pred["id"].nunique() == 46 and len(pred) == 46 * 100
    # observed entries of each patient are kept in the completion Algorithm 1 returns
    obs = pd.read_csv(work / "results/ehr/patients.csv", index_col="patient")
    first = pred.groupby("id").first()
    for n in registry.OUTPUT_NAMES:
        seen = obs[n].notna()
        np.testing.assert_allclose(first.loc[obs.index[seen], "completed_" + n], obs.loc[seen, n])
    ood = pd.read_csv(work / "results/tables/ehr_ood_delta0.5.csv")
    assert len(ood) == 46 and ood["ood_percentile"].between(0, 100).all()
