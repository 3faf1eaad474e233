"""The data stage run by Snakemake on the smoke config, in a copy of the workflow."""
import json

import pandas as pd
import pytest

from conftest import copy_workflow, snakemake
from cvsim6.data import datasets


@pytest.mark.slow
def test_data_stage_end_to_end(tmp_path):
    work = copy_workflow(tmp_path)
    targets = [f"results/data/{s}/{f}" for s in ("structural", "ehr")
               for f in ("manifest.json", "outputs_histograms.png", "inputs_histograms.png")]
    proc = snakemake("--cores", "2", *targets, "--configfile", "config/smoke.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    for study in ("structural", "ehr"):
        m = json.loads((work / f"results/data/{study}/manifest.json").read_text())
        assert m["n_samples"] == 300
        assert sum(m["split_sizes"].values()) == 300 - m["n_failed"]
        assert m["split_sizes"]["validation"] == 40
        for split in datasets.SPLITS:
            df = datasets.read_dataset(work / f"results/data/{study}/{split}.parquet")
            assert len(df) == m["split_sizes"][split]
        # each of the three shard jobs logged its rate
        for i in (1, 2, 3):
            log = (work / f"logs/simulate_shard/{study}_{i}-of-3.log").read_text()
            assert "sets/s" in log
        assert (work / f"results/data/{study}/outputs_histograms.pdf").is_file()
    # the same seed and config with another shard count gives identical data
    train = pd.read_parquet(work / "results/data/structural/train.parquet")
    (work / "shards2.yaml").write_text("data:\n  n_shards: 2\n")
    proc = snakemake("--cores", "2", "results/data/structural/train.parquet", "--configfile",
                     "config/smoke.yaml", "shards2.yaml", "--forceall", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (work / "results/data/structural/shards/simulated_2-of-2.parquet").is_file()
    pd.testing.assert_frame_equal(pd.read_parquet(work / "results/data/structural/train.parquet"), train)
