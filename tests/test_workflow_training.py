"""The training stage run by Snakemake on the smoke config, in a copy of the workflow."""
import pandas as pd
import pytest

from cvsim6 import networks
from test_workflow import copy_workflow, snakemake


@pytest.mark.slow
def test_training_stage_end_to_end(tmp_path):
    work = copy_workflow(tmp_path)
    targets = ["results/tables/structural_emulator_validation.md",
               "results/tables/ehr_architectures.md",
               "results/tables/structural_schedules.md",
               "results/models/ehr/encoder_decoder_delta0.5.pt",
               "results/models/ehr/flow_delta2.pt",
               "results/training/ehr/emulator_l2_errors.json",
               "results/training/structural/flow_delta0_marginals.png",
               "results/training/ehr/encoder_decoder_delta0.5_losses.png",
               "results/training/structural/encoder_decoder_delta0_losses.png"]
    proc = snakemake("--cores", "2", *targets, "--configfile", "config/smoke.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # models load, with the architecture of the config and the noise level of the file name
    ed, info = networks.load_model(work / "results/models/ehr/encoder_decoder_delta0.5.pt", with_info=True)
    assert info["noise_level"] == 0.5 and info["stage"] == "encoder_decoder"
    flow, info = networks.load_model(work / "results/models/ehr/flow_delta2.pt", with_info=True)
    assert info["noise_level"] == 2.0 and networks.count_parameters(flow) == 20280
    # per-epoch losses of every stage, as many rows as configured epochs
    losses = pd.read_csv(work / "results/training/ehr/encoder_decoder_delta0.5_losses.csv")
    assert list(losses["epoch"]) == [1, 2]
    assert losses[["train_loss", "test_loss"]].notna().all().all()
    assert (work / "results/training/ehr/encoder_decoder_delta0.5_losses.png").is_file()
    # the structural encoder/decoder (restarts: 2 in the smoke config): each candidate trained in
    # a job of its own (log, benchmark), the run chose by their test losses at the choice
    _, info = networks.load_model(work / "results/models/structural/encoder_decoder_delta0.pt", with_info=True)
    restart = info["restart"]
    cands = [pd.read_csv(work / f"results/models/structural/encoder_decoder_delta0.pt.ckpt.candidate{c}.csv")
             for c in range(2)]
    assert restart["test_loss"] == [float(df.loc[df["epoch"] == restart["epochs"], "test_loss"].iloc[0])
                                    for df in cands]
    assert restart["chosen"] == min(range(2), key=lambda c: (restart["test_loss"][c], c))
    for c in range(2):
        assert "done" in (work / f"logs/train_encoder_decoder_candidate/structural_delta0_{c}.log").read_text()
        assert (work / f"benchmarks/train_encoder_decoder_candidate/structural_delta0_{c}.tsv").is_file()
    # the generated appendix tables state what was run
    arch = pd.read_csv(work / "results/tables/ehr_architectures.csv")
    assert (arch["Parameters"] == arch["Parameters (paper)"]).all()
    import json

    l2 = json.loads((work / "results/training/ehr/emulator_l2_errors.json").read_text())
    assert l2["n"] == 40 and 0 < l2["mean"] <= l2["max"]
    assert (work / "results/training/structural/flow_delta0_marginals.pdf").is_file()
    # the smoke config floors the structural emulator's output variances (not the EHR one's): the
    # losses then carry the plain MSE beside the weighted loss, and the schedule table says so
    emu = pd.read_csv(work / "results/training/structural/emulator_losses.csv")
    assert {"train_mse", "test_mse"} <= set(emu.columns) and emu["train_mse"].notna().all()
    assert "train_mse" not in pd.read_csv(work / "results/training/ehr/emulator_losses.csv").columns
    sched = pd.read_csv(work / "results/tables/structural_schedules.csv").set_index("Module")
    assert "output variances floored at 0.01" in sched.loc["NN_e", "Schedule"]
    assert "floored" not in sched.loc["NN_f", "Schedule"]
    assert "KL weight ramped up over the first 1 epoch" in sched.loc["NN_v + NN_d", "Schedule"]
    val = pd.read_csv(work / "results/tables/structural_emulator_validation.csv")
    assert len(val) == 16 and (val["Mean (ours)"] > 0).all() and "Mean (paper)" in val
    # the loss figures are drawn by a rule of their own: a change of the plotting code redraws
    # them and retrains nothing
    with open(work / "src/cvsim6/loss_plots.py", "a") as fh:
        fh.write("\n# changed\n")
    proc = snakemake("-n", *targets, "--configfile", "config/smoke.yaml", cwd=work)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Updated input files: src/cvsim6/loss_plots.py" in out
    assert "plot_training_losses" in out and "train_encoder_decoder" not in out and "train_emulator" not in out
