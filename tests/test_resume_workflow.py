"""A whole Snakemake run killed during training resumes from the training checkpoint.

The smoke config's structural emulator (rule train_emulator), with more epochs so that
the run can be caught mid-training (smoke trains 3 epochs, a few tens of milliseconds):
an uninterrupted run gives the reference weights; then, in a copy of that workflow, the
rule is forced to run again, and the whole Snakemake process group is killed (SIGKILL, as
the OOM killer or a lost node would; SIGTERM, as a scheduler or ``kill`` would) once the
job's checkpoint file exists and 10 epochs are done. The command a user would run next
(after SIGKILL: ``snakemake --unlock``; then the same command with ``--rerun-incomplete``)
must resume from the checkpoint and end with exactly the reference weights.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest
import torch

from conftest import SNAKEMAKE, copy_workflow, snakemake

pytestmark = pytest.mark.slow

MODEL = "results/models/structural/emulator.pt"
CHECKPOINT = MODEL + ".ckpt"  # cvsim6.training.loop's default: the model path + ".ckpt"
LOSSES = "results/training/structural/emulator_losses.csv"  # one row per epoch, appended
EPOCHS = 300
KILL_AFTER = 10
LONGER = f"""# smoke config, but the structural emulator trains long enough to be interrupted
training:
  checkpoint_every: 2
  studies:
    structural:
      emulator: {{epochs: {EPOCHS}}}
"""
ARGS = [MODEL, "--configfile", "config/smoke.yaml", "longer.yaml"]


def weights(work: Path) -> dict:
    return torch.load(work / MODEL, weights_only=True)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The workflow after an uninterrupted run: data simulated, emulator trained, checkpoint kept."""
    work = copy_workflow(tmp_path_factory.mktemp("resume") / "reference")
    (work / "longer.yaml").write_text(LONGER)
    proc = snakemake("--cores", "2", *ARGS, cwd=work)
    assert proc.returncode == 0, proc.stderr[-5000:]
    assert torch.load(work / CHECKPOINT, weights_only=True)["epoch"] == EPOCHS
    return work


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killed_run_resumes_training_from_checkpoint(reference, tmp_path, sig):
    work = tmp_path / "work"
    shutil.copytree(reference, work, symlinks=True)  # results, logs and .snakemake metadata
    (work / CHECKPOINT).unlink()  # not an output of the rule: --forcerun leaves it

    # Train again and kill the whole snakemake process group once a checkpoint exists and
    # KILL_AFTER epochs are done (a resume at a later epoch, learning rate already decayed).
    def caught_mid_training() -> bool:
        losses = work / LOSSES
        return ((work / CHECKPOINT).exists() and losses.exists()
                and len(losses.read_text().splitlines()) > KILL_AFTER)

    with open(tmp_path / "killed.out", "w") as out:
        run = subprocess.Popen([SNAKEMAKE, "--cores", "2", *ARGS, "--forcerun", "train_emulator"], cwd=work,
                               stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               start_new_session=True)
        try:
            end = time.monotonic() + 300
            while not caught_mid_training() and run.poll() is None and time.monotonic() < end:
                time.sleep(0.02)
            os.killpg(run.pid, sig)
            run.wait(timeout=60)
        finally:
            if run.poll() is None:
                os.killpg(run.pid, signal.SIGKILL)
                run.wait(timeout=60)
    killed_log = (tmp_path / "killed.out").read_text()
    assert not (work / MODEL).exists(), f"training ended before the kill; raise EPOCHS\n{killed_log[-3000:]}"
    stopped_at = torch.load(work / CHECKPOINT, weights_only=True)["epoch"]
    assert KILL_AFTER - 2 <= stopped_at < EPOCHS  # checkpoints every 2 epochs

    # What a user does next.
    if sig == signal.SIGKILL:  # snakemake had no chance to release its lock
        locked = snakemake("--cores", "2", *ARGS, "--rerun-incomplete", cwd=work)
        assert locked.returncode != 0 and "--unlock" in locked.stderr, locked.stderr[-3000:]
        assert snakemake("--unlock", *ARGS, cwd=work).returncode == 0
    proc = snakemake("--cores", "2", *ARGS, "--rerun-incomplete", cwd=work)
    assert proc.returncode == 0, proc.stderr[-5000:]
    assert "train_emulator" in proc.stdout + proc.stderr

    logs = "\n".join(p.read_text(errors="replace") for p in (work / "logs").rglob("*.log"))
    resumed = re.findall(rf"resuming from \S*emulator\.pt\.ckpt at epoch (\d+)/{EPOCHS}", logs)
    assert resumed == [str(stopped_at)], resumed

    ref, got = weights(reference), weights(work)
    assert ref["state_dict"].keys() == got["state_dict"].keys()
    for name, tensor in ref["state_dict"].items():
        assert torch.equal(tensor, got["state_dict"][name]), name
    assert got["info"] == ref["info"]  # final losses, epochs done, ...
    losses = [pd.read_csv(w / LOSSES).drop(columns=["seconds", "cpu_seconds"])
              for w in (reference, work)]
    pd.testing.assert_frame_equal(losses[0], losses[1], check_exact=True)
    assert list(losses[1]["epoch"]) == list(range(1, EPOCHS + 1))
