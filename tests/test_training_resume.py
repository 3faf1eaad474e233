"""Training (cvsim6.training): resume after a kill, checkpoints, seeding, guards."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from cvsim6.training import fingerprint
from cvsim6.training import train as tr
from cvsim6.training.stages import EmulatorStage, EncoderDecoderStage, FlowStage

from training_helpers import EMU, FLOW, ENCDEC, paths, state_dict, assert_same_weights, encdec_run


class Killed(RuntimeError):
    """The simulated kill of a training run part-way through."""


#: The step schedule evaluating every epoch, and the cosine schedule keeping the best weights
#: of an evaluation every second epoch (the best weights travel in the checkpoint).
_SCHEDULES = {"step": {}, "cosine-best": {"lr_schedule": "cosine", "warmup_epochs": 2, "keep_best": True,
                                          "eval_every": 2, "lr_final": 0.05}}


@pytest.mark.parametrize("schedule", sorted(_SCHEDULES))
@pytest.mark.parametrize("stage", ["emulator", "flow", "encoder_decoder"])
def test_resume_after_kill_gives_identical_weights(stage, schedule, data, emulator, tmp_path, monkeypatch):
    hyper = {"emulator": EMU, "flow": FLOW, "encoder_decoder": ENCDEC}[stage] | {"epochs": 7} | _SCHEDULES[schedule]
    if stage == "encoder_decoder" and schedule == "cosine-best":
        hyper |= {"kl_warmup_epochs": 5}  # the KL weight depends on the epoch: resumes must restore it
    fn = {"emulator": tr.train_emulator, "flow": tr.train_flow, "encoder_decoder": tr.train_encoder_decoder}[stage]
    extra = {} if stage == "emulator" else {"noise_level": 0.5}
    if stage == "encoder_decoder":
        extra["emulator"] = str(emulator[0] / "emulator.pt")

    def run(d, **kw):
        d.mkdir(exist_ok=True)
        return fn(str(data[0]), str(data[1]), hyper=hyper, seed=3, device="cpu", progress=False,
                  checkpoint_every=2, **extra, **paths(d, "m"), **kw)

    full = run(tmp_path / "full")
    assert full["completed"]

    # 1) stopped cleanly after 3 epochs, then rerun
    part = run(tmp_path / "split", max_epochs_this_run=3)
    assert part == {**part, "completed": False, "epochs_done": 3}
    assert not (tmp_path / "split" / "m.pt").exists() and (tmp_path / "split" / "m.pt.ckpt").exists()
    assert run(tmp_path / "split")["completed"]
    assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "split" / "m.pt")

    # 2) killed in the middle of epoch 6 (last checkpoint: epoch 4), then rerun
    cls = {"emulator": EmulatorStage, "flow": FlowStage, "encoder_decoder": EncoderDecoderStage}[stage]
    original = cls.batch_loss
    calls = {"n": 0}
    batches_per_epoch = 400 // hyper["batch_size"] + (400 % hyper["batch_size"] >= 2)

    def dying(self, idx):
        calls["n"] += 1
        if calls["n"] > 5 * batches_per_epoch + 2:
            raise Killed
        return original(self, idx)

    monkeypatch.setattr(cls, "batch_loss", dying)
    with pytest.raises(Killed):
        run(tmp_path / "killed")
    monkeypatch.setattr(cls, "batch_loss", original)
    assert len(pd.read_csv(tmp_path / "killed" / "m.csv")) == 5
    assert torch.load(tmp_path / "killed" / "m.pt.ckpt", weights_only=True)["epoch"] == 4
    assert run(tmp_path / "killed")["completed"]
    assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "killed" / "m.pt")
    a = pd.read_csv(tmp_path / "full" / "m.csv").drop(columns=["seconds", "cpu_seconds"])
    b = pd.read_csv(tmp_path / "killed" / "m.csv").drop(columns=["seconds", "cpu_seconds"])
    pd.testing.assert_frame_equal(a, b)

    # 3) a finished run rerun with the same arguments only re-writes the outputs
    assert run(tmp_path / "full")["epochs_done"] == 7
    assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "killed" / "m.pt")


def test_changed_hyper_ignores_checkpoint(data, tmp_path):
    kw = dict(seed=1, device="cpu", progress=False, **paths(tmp_path, "m"))
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 4}, max_epochs_this_run=2, **kw)
    res = tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 4, "lr": 1e-3}, **kw)
    assert res["completed"]
    df = pd.read_csv(tmp_path / "m.csv")
    assert df["epoch"].tolist() == [1, 2, 3, 4] and df["lr"].iloc[0] == 1e-3


def test_checkpoint_of_other_training_code_is_not_reused(data, tmp_path, monkeypatch):
    """A finished checkpoint is reused by the code that wrote it (nothing retrained) and never by
    other training code: a rerun after a code change retrains instead of re-saving old weights."""
    kw = dict(hyper=EMU | {"epochs": 3}, seed=1, device="cpu", progress=False, **paths(tmp_path, "m"))
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 3
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 0
    real = fingerprint.training_code_digest()
    assert len(real) == 64 and real == fingerprint.training_code_digest()
    monkeypatch.setattr(fingerprint, "training_code_digest", lambda: "edited" + real[6:])
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 3


def test_training_code_digest_covers_the_training_rules_code_inputs():
    """Every source a training rule declares as its ``code`` input enters the checkpoints' digest."""

    from cvsim6.workflow.codegraph import module_closure

    root = Path(fingerprint.__file__).resolve().parents[1]
    hashed = {root / s for s in fingerprint.DIGEST_SOURCES if s.endswith(".py")}
    hashed |= {f for s in fingerprint.DIGEST_SOURCES if not s.endswith(".py") for f in (root / s).rglob("*.py")}
    closure = {Path(f).resolve() for f in module_closure("cvsim6.training.train", root)}
    assert {root / "training" / "train.py", root / "seeding.py", root / "workflow" / "config.py"} <= closure
    assert closure <= hashed, sorted(str(f) for f in closure - hashed)


def test_non_finite_loss_keeps_the_last_good_checkpoint(data, emulator, tmp_path, monkeypatch):
    orig, calls = EncoderDecoderStage.batch_loss, {"n": 0}

    def batch_loss(self, idx):  # a nan loss in the second epoch (13 steps per epoch)
        loss, parts = orig(self, idx)
        calls["n"] += 1
        return (loss * math.nan if calls["n"] == 16 else loss), parts

    monkeypatch.setattr(EncoderDecoderStage, "batch_loss", batch_loss)
    with pytest.raises(FloatingPointError, match="non-finite loss at epoch 2"):
        encdec_run(data, emulator, tmp_path, {"epochs": 4}, checkpoint_every=1)
    good = torch.load(tmp_path / "m.pt.ckpt", weights_only=True)
    failed = torch.load(tmp_path / "m.pt.ckpt.nonfinite", weights_only=True)
    assert good["epoch"] == 1 and failed["epoch"] == 2
    assert all(torch.isfinite(v).all() for v in good["model"].values())
    assert any(not torch.isfinite(v).all() for v in failed["model"].values())


def test_seed_controls_result(data, tmp_path):
    def run(name, seed):
        tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 2}, seed=seed, device="cpu",
                          progress=False, **paths(tmp_path, name))
        return tmp_path / f"{name}.pt"

    assert_same_weights(run("a", 7), run("b", 7))
    with pytest.raises(AssertionError):
        assert_same_weights(run("c", 7), run("d", 8))


def _encdec_weights(data, emulator, tmp_path, name, hyper, scale_call=None, scale=1.0, monkeypatch=None):
    """Train the small encoder/decoder; optionally multiply the loss of one training step
    (call number ``scale_call``) by ``scale``; return the saved weights."""
    if scale_call is not None:
        calls = {"n": 0}
        orig = EncoderDecoderStage.batch_loss

        def batch_loss(self, idx):
            loss, parts = orig(self, idx)
            calls["n"] += 1
            return (loss * scale if calls["n"] == scale_call else loss), parts
        monkeypatch.setattr(EncoderDecoderStage, "batch_loss", batch_loss)
    try:
        tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                 hyper=ENCDEC | {"epochs": 3} | hyper, seed=3, device="cpu", progress=False,
                                 **paths(tmp_path, name))
    finally:
        if monkeypatch is not None:
            monkeypatch.undo()
    return state_dict(tmp_path / f"{name}.pt")


def test_grad_clip_is_a_guard_that_only_acts_on_outlier_steps(data, emulator, tmp_path, monkeypatch):
    """grad_clip set far above every normal gradient norm leaves a step untouched (bit for bit),
    and a step whose norm is not finite (seed 2024's structural KL spikes overflowed float32) is
    skipped instead of poisoning Adam's moments."""
    plain = _encdec_weights(data, emulator, tmp_path, "plain", {})
    guarded = _encdec_weights(data, emulator, tmp_path, "guarded", {"grad_clip": 1.0e5})
    for k in plain:
        assert torch.equal(plain[k], guarded[k]), k
    assert "skipped_steps" not in pd.read_csv(tmp_path / "plain.csv")
    assert pd.read_csv(tmp_path / "guarded.csv")["skipped_steps"].tolist() == [0, 0, 0]
    # step 5's loss x 1e36 (gradient norm overflows to inf) or x nan: the step is skipped, the
    # epoch's mean loss leaves it out, the CSV counts it
    spiked = _encdec_weights(data, emulator, tmp_path, "spiked", {"grad_clip": 1.0e5}, 5, 1e36, monkeypatch)
    nan = _encdec_weights(data, emulator, tmp_path, "nan", {"grad_clip": 1.0e5}, 5, math.nan, monkeypatch)
    for k in spiked:
        assert torch.isfinite(spiked[k]).all() and torch.equal(spiked[k], nan[k]), k
    df, ref = pd.read_csv(tmp_path / "spiked.csv"), pd.read_csv(tmp_path / "guarded.csv")
    assert df["skipped_steps"].tolist() == [1, 0, 0]
    assert np.isfinite(df["train_loss"]).all() and df["train_loss"].iloc[0] < 2 * ref["train_loss"].iloc[0]
    assert any(not torch.equal(spiked[k], guarded[k]) for k in guarded)  # one update fewer
    # without the guard the same spike is applied and moves the weights elsewhere; a nan loss ends the run
    unguarded = _encdec_weights(data, emulator, tmp_path, "unguarded", {}, 5, 1e36, monkeypatch)
    assert any(not torch.equal(unguarded[k], spiked[k]) for k in spiked)
    with pytest.raises(FloatingPointError, match="non-finite loss at epoch 1"):
        _encdec_weights(data, emulator, tmp_path, "unguarded_nan", {}, 5, math.nan, monkeypatch)
    # a clip that does act changes the run
    tight = _encdec_weights(data, emulator, tmp_path, "tight", {"grad_clip": 1.0e-3})
    assert any(not torch.equal(tight[k], plain[k]) for k in plain)


def test_resume_from_a_checkpoint_without_skipped_steps(data, tmp_path):
    """A completed or interrupted checkpoint written before ``skipped_steps`` existed resumes:
    its rows keep an empty cell there, the new rows count."""
    kw = dict(seed=1, device="cpu", progress=False, **paths(tmp_path, "m"))
    hyper = EMU | {"epochs": 4, "grad_clip": 1.0e5}
    tr.train_emulator(str(data[0]), str(data[1]), hyper=hyper, max_epochs_this_run=2, **kw)
    ckpt = tmp_path / "m.pt.ckpt"
    ck = torch.load(ckpt, weights_only=True)
    ck["history"] = [{k: v for k, v in r.items() if k != "skipped_steps"} for r in ck["history"]]
    torch.save(ck, ckpt)
    assert tr.train_emulator(str(data[0]), str(data[1]), hyper=hyper, **kw)["completed"]
    df = pd.read_csv(tmp_path / "m.csv")
    assert df["epoch"].tolist() == [1, 2, 3, 4]
    assert df["skipped_steps"].isna().tolist() == [True, True, False, False]
    assert (df["skipped_steps"].iloc[2:] == 0).all()


