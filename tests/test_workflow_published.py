"""Both network sources through the whole smoke workflow: the paper's published networks
(no training), then this workflow's own, side by side in one results/ tree and one scorecard."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pandas as pd
import pytest
import yaml

from cvsim6 import networks, paper_values
from test_workflow import copy_workflow, snakemake

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not (SHARED / "paper_networks").is_dir() or not (SHARED / "EHR_dataset.csv").is_file(),
                       reason="local copies of the published networks and the EHR data not present"),
]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_published_and_trained_results_sit_side_by_side(tmp_path):
    work = copy_workflow(tmp_path)
    local = work / "local.yaml"
    local.write_text(yaml.safe_dump({"ehr_data": {"path": str(SHARED / "EHR_dataset.csv")},
                                     "networks": {"published": {"path": str(SHARED / "paper_networks")}}}))
    smoke = ["--configfile", "config/smoke.yaml", str(local)]

    proc = snakemake("--cores", "2", "all", *smoke, "config/published.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    pub = work / "results" / "published"
    # the converted networks: the paper's architecture, float64, with their origin recorded
    flow, info = networks.load_model(pub / "models/ehr/flow_delta0.5.pt", with_info=True)
    assert info["source"] == "published" and info["noise_level"] == 0.5
    assert networks.count_parameters(flow) == paper_values.PARAMETER_COUNTS["ehr"]["NN_f"]
    assert not (work / "results/models").exists()  # nothing was trained
    assert not list((work / "logs").glob("train_*"))
    for rel in ("tables/ehr_error_per_output.md", "tables/structural_inversion_errors.md",
                "structural/manifold_svd.png", "ehr/patient_predictions_delta0.5.png",
                "training/ehr/emulator_l2_errors.png", "tables/structural_emulator_validation.md"):
        assert (pub / rel).is_file(), rel
    card = pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline")
    assert "published / paper" in card.columns and "trained" not in card.columns
    lam = card[card.index.str.startswith("Stiffness")]
    assert len(lam) == 8
    # the published emulator on our (smoke) validation sets: the paper's appendix C accuracy
    emulator_row = card.loc[card.index.str.startswith("Structural emulator, mean")].iloc[0]
    assert 0.5 < emulator_row["published / paper"] < 2.0
    published_table = digest(pub / "tables/ehr_error_per_output.csv")

    proc = snakemake("--cores", "2", "all", *smoke, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (work / "results/models/ehr/flow_delta0.5.pt").is_file()
    assert digest(pub / "tables/ehr_error_per_output.csv") == published_table  # not overwritten
    card = pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline")
    assert {"trained", "trained / paper", "published", "published / paper"} <= set(card.columns)
    # the stiffness rows do not depend on the networks: one value for both sources
    lam = card[card.index.str.startswith("Stiffness")]
    pd.testing.assert_series_equal(lam["trained"], lam["published"], check_names=False)
    md = (work / "results/report/reproduction.md").read_text()
    assert "**trained**" in md and "**published**" in md
