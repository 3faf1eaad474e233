"""Training (cvsim6.training): losses fall, noise injection, outputs, resume, seeding."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from cvsim6 import nets as nw
from cvsim6 import seeding
from cvsim6.data.datasets import load_split
from cvsim6.training import fingerprint, loop, loss_weights, optimization, restarts, stages
from cvsim6.training import hyperparameters as hp
from cvsim6.training import train as tr
from cvsim6.training.stages import EmulatorStage, EncoderDecoderStage, FlowStage
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES, default_parameters, noise_std

ROOT = Path(__file__).resolve().parents[1]
EMU = dict(hidden=32, layers=3, epochs=25, batch_size=32, lr=3e-3, lr_step=10, lr_gamma=0.7)
FLOW = dict(hidden=16, blocks=4, layers_per_block=4, batchnorm=True, epochs=40, batch_size=64, lr=5e-3,
            lr_step=20, lr_gamma=0.7, weight_decay=1e-5)
ENCDEC = dict(latent_dim=7, encoder_hidden=16, encoder_layers=3, decoder_hidden=32, decoder_layers=3,
              beta_d=1.0, beta_v=0.05, beta_r=0.5, epochs=25, batch_size=32, lr=3e-3, lr_step=10, lr_gamma=0.7)



def _synthetic(n: int, seed: int) -> pd.DataFrame:
    """Smooth map 23 -> 16 with outputs on the scale of the registry noise (x 10)."""
    rng = np.random.default_rng(seed)
    v = default_parameters() * rng.uniform(0.7, 1.3, size=(n, 23))
    u = (v / default_parameters() - 1.0) / 0.3  # in [-1, 1]
    a = np.random.default_rng(123).normal(size=(23, 16)) / np.sqrt(23)
    y = np.tanh(u @ a) + 0.3 * np.sin(2 * u[:, :16])
    y = 100.0 + 10.0 * noise_std() * y
    y[:, 0] = v[:, 0]  # output Hr is the input Hr: one shared column, as in the real datasets
    df = pd.DataFrame(v, columns=list(PARAMETER_NAMES))
    for j, name in enumerate(OUTPUT_NAMES):
        df[name] = y[:, j]
    assert df.shape[1] == 38
    return df


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("data")
    _synthetic(400, 1).to_parquet(d / "train.parquet")
    _synthetic(100, 2).to_parquet(d / "test.parquet")
    return d / "train.parquet", d / "test.parquet"


def _paths(d, name):
    return dict(model=str(d / f"{name}.pt"), losses=str(d / f"{name}.csv"))


@pytest.fixture(scope="module")
def emulator(data, tmp_path_factory):
    d = tmp_path_factory.mktemp("emu")
    res = tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU, seed=0, device="cpu", progress=False,
                            **_paths(d, "emulator"))
    return d, res


# ----------------------------------------------------------------------------- losses fall
def test_emulator_trains(emulator, data):
    d, res = emulator
    assert res["completed"] and res["epochs_done"] == EMU["epochs"]
    df = pd.read_csv(d / "emulator.csv")
    assert list(df.columns) == ["epoch", "train_loss", "test_loss", "lr", "seconds", "cpu_seconds"]
    assert df["epoch"].tolist() == list(range(1, EMU["epochs"] + 1))
    assert df["test_loss"].iloc[-1] < 0.25 * df["test_loss"].iloc[0]
    assert df["train_loss"].iloc[-1] < 0.25 * df["train_loss"].iloc[0]
    # StepLR stepped per epoch: lr of epoch e is lr * gamma^floor((e-1)/step)
    expected = EMU["lr"] * EMU["lr_gamma"] ** ((df["epoch"] - 1) // EMU["lr_step"])
    assert np.allclose(df["lr"], expected)
    assert not list(d.glob("*.png"))  # figures are drawn from the CSV elsewhere (cvsim6.reporting.loss_figures)
    model, info = nw.load_model(d / "emulator.pt", with_info=True)
    assert info["stage"] == "emulator" and info["noise_level"] == 0.0 and info["hyper"]["hidden"] == 32
    # physical-units prediction is better than predicting the mean
    test = pd.read_parquet(data[1])
    v, y = test[list(PARAMETER_NAMES)].to_numpy(), test[list(OUTPUT_NAMES)].to_numpy()
    err = ((model.predict(v) - y) / model.y_scaler.std.double().numpy()) ** 2  # training-set scaling
    assert err.mean() < 0.25
    assert info["final_test_loss"] == pytest.approx(err.mean(), rel=1e-3)


def test_emulator_with_linear_skip_and_log_inputs(emulator, data, tmp_path):
    """log_inputs takes every parameter whose training values are positive (all but P_th here),
    and the skip learns the synthetic data's exactly linear output (Hr, the input Hr) far better
    than the plain MLP of the same seed and schedule."""
    res = tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"linear_skip": True, "log_inputs": True},
                            seed=0, device="cpu", progress=False, **_paths(tmp_path, "emulator"))
    assert res["completed"]
    model = nw.load_model(tmp_path / "emulator.pt")
    v_tr = pd.read_parquet(data[0])[list(PARAMETER_NAMES)].to_numpy()
    positive = [j for j in range(len(PARAMETER_NAMES)) if v_tr[:, j].min() > 0]
    assert model.config["log_inputs"] == positive and PARAMETER_NAMES.index("P_th") not in positive
    assert model.config["linear_skip"] and len(positive) == len(PARAMETER_NAMES) - 1
    plain = nw.load_model(emulator[0] / "emulator.pt")
    test = pd.read_parquet(data[1])
    v, y = test[list(PARAMETER_NAMES)].to_numpy(), test[list(OUTPUT_NAMES)].to_numpy()
    hr = OUTPUT_NAMES.index("Hr")
    err_skip = np.abs(model.predict(v)[:, hr] - y[:, hr]).mean()
    err_plain = np.abs(plain.predict(v)[:, hr] - y[:, hr]).mean()
    assert err_skip < 0.7 * err_plain  # 0.96 against 1.82 bpm when written


def test_flow_trains(data, tmp_path):
    res = tr.train_flow(str(data[0]), str(data[1]), hyper=FLOW, seed=0, noise_level=0.5, device="cpu",
                        progress=False, **_paths(tmp_path, "flow"))
    assert res["completed"]
    df = pd.read_csv(tmp_path / "flow.csv")
    assert df["train_loss"].iloc[-1] < df["train_loss"].iloc[0] - 3.0  # nats
    assert df["test_loss"].iloc[-1] < df["test_loss"].iloc[0] - 0.75  # small data: overfits soon
    flow = nw.load_model(tmp_path / "flow.pt")
    assert isinstance(flow, nw.RealNVP) and flow.config["batchnorm"]
    y = flow.sample_physical(200, torch.Generator().manual_seed(0))
    assert y.shape == (200, 16) and np.isfinite(y).all()


def test_encoder_decoder_trains(data, emulator, tmp_path):
    res = tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                   hyper=ENCDEC, seed=0, noise_level=0.25, device="cpu", progress=False,
                                   **_paths(tmp_path, "encdec"))
    assert res["completed"]
    df = pd.read_csv(tmp_path / "encdec.csv")
    for p in ("decoder", "kl", "reeval"):
        assert f"train_{p}" in df and f"test_{p}" in df
    assert df["train_loss"].iloc[-1] < 0.5 * df["train_loss"].iloc[0]
    assert df["test_loss"].iloc[-1] < 0.5 * df["test_loss"].iloc[0]
    assert df["test_decoder"].iloc[-1] < 0.6 * df["test_decoder"].iloc[0]
    assert df["test_reeval"].iloc[-1] < df["test_reeval"].iloc[0]
    # total = beta_d * decoder + beta_v * kl + beta_r * reeval (test losses: deterministic terms)
    total = ENCDEC["beta_d"] * df["test_decoder"] + ENCDEC["beta_v"] * df["test_kl"] + ENCDEC["beta_r"] * df["test_reeval"]
    assert np.allclose(total, df["test_loss"], rtol=1e-5)
    model = nw.load_model(tmp_path / "encdec.pt")
    assert isinstance(model, nw.EncoderDecoder)


def test_encoder_decoder_with_log_parameters(data, emulator, tmp_path):
    """log_parameters: the model standardizes the logarithm of every parameter positive in the
    training data (all but P_th); its losses fall, and no latent draw, however far out, decodes a
    parameter <= 0 there."""
    res = tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                   hyper=ENCDEC | {"log_parameters": True}, seed=0, noise_level=0.25,
                                   device="cpu", progress=False, **_paths(tmp_path, "encdec"))
    assert res["completed"]
    df = pd.read_csv(tmp_path / "encdec.csv")
    assert df["test_decoder"].iloc[-1] < 0.6 * df["test_decoder"].iloc[0]
    assert df["test_reeval"].iloc[-1] < df["test_reeval"].iloc[0]
    model = nw.load_model(tmp_path / "encdec.pt")
    positive = [j for j in range(len(PARAMETER_NAMES)) if j != PARAMETER_NAMES.index("P_th")]
    assert model.config["log_params"] == positive and isinstance(model.x_scaler, nw.LogStandardizer)
    test = pd.read_parquet(data[1])
    y = test[list(OUTPUT_NAMES)].to_numpy()
    w = np.random.default_rng(0).normal(0.0, 4.0, (len(y), ENCDEC["latent_dim"]))
    v = model.invert(y, w)
    assert np.isfinite(v).all() and (v[:, positive] > 0).all()
    with pytest.raises(ValueError, match="log_parameters must be true or false"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"log_parameters": "yes"})


def test_encoder_decoder_with_prior_reevaluation(data, emulator, tmp_path):
    """beta_prior: the losses CSV gains the prior-draw re-evaluation columns, the test total is
    the weighted sum of its four terms, and the term falls while training; a weight that is
    not a number >= 0 is refused by name."""
    hyper = ENCDEC | {"beta_prior": 5.0}
    res = tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                   hyper=hyper, seed=0, noise_level=0.25, device="cpu", progress=False,
                                   **_paths(tmp_path, "encdec"))
    assert res["completed"]
    df = pd.read_csv(tmp_path / "encdec.csv")
    total = (ENCDEC["beta_d"] * df["test_decoder"] + ENCDEC["beta_v"] * df["test_kl"]
             + ENCDEC["beta_r"] * df["test_reeval"] + 5.0 * df["test_prior_reeval"])
    assert np.allclose(total, df["test_loss"], rtol=1e-5)
    assert df["test_prior_reeval"].iloc[-1] < 0.5 * df["test_prior_reeval"].iloc[0]
    for bad in (-1.0, True, "1", float("nan")):
        with pytest.raises(ValueError, match="beta_prior must be a number >= 0"):
            hp.check_hyper("encoder_decoder", ENCDEC | {"beta_prior": bad})


@pytest.mark.parametrize("config_file", ["config.yaml", "paper.yaml"])
def test_configured_loss_weights_keep_the_latent_space_alive(config_file, data, emulator, tmp_path):
    """The shipped weights must leave information in w: the synthetic map has 7 more inputs
    than outputs, so an informative latent space has KL well above 0 nats. The paper's table
    values read literally (KL weighted 2000, summed errors) collapse it: KL -> 0."""
    from pathlib import Path

    from cvsim6.workflow.config import load_config

    cfg = load_config(Path(__file__).parents[1] / "config" / config_file)
    shipped = cfg["training"]["studies"]["structural"]["encoder_decoder"]
    weights = {k: shipped[k] for k in ("beta_d", "beta_v", "beta_r", "reduction")}
    kl = {}
    for name, w in (("shipped", weights), ("literal", dict(beta_d=1, beta_v=2000, beta_r=20, reduction="sum"))):
        hyper = dict(ENCDEC, **w, epochs=30)
        tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                 hyper=hyper, seed=0, device="cpu", progress=False, **_paths(tmp_path, name))
        kl[name] = pd.read_csv(tmp_path / f"{name}.csv")["test_kl"].iloc[-1]
    assert kl["shipped"] > 2.0, kl
    assert kl["literal"] < 0.05, kl


# ----------------------------------------------------------------------------- noise injection
def _stages(noise_level):
    rng = np.random.default_rng(5)
    n = 20_000
    v, y = rng.normal(size=(n, 23)), rng.normal(size=(n, 16))
    flow = nw.RealNVP(hidden=4, blocks=2)
    flow.y_scaler.std.copy_(torch.as_tensor(np.linspace(0.5, 2000.0, 16)))
    encdec = nw.EncoderDecoder(latent_dim=3, encoder_hidden=4, encoder_layers=2, decoder_hidden=4, decoder_layers=2)
    encdec.y_scaler.load_state_dict(flow.y_scaler.state_dict())
    emu = nw.Emulator(hidden=4, layers=2)
    g = torch.Generator().manual_seed(0)
    cpu = torch.device("cpu")
    return (FlowStage(flow, y, y[:10], noise_level, g, cpu),
            EncoderDecoderStage(encdec, emu, v, y, v[:10], y[:10], noise_level, hp.check_hyper("encoder_decoder", dict(ENCDEC, reduction="sum")), g, cpu),
            EmulatorStage(emu, v, y, v[:10], y[:10], cpu))


@pytest.mark.parametrize("delta", [0.5, 2.0])
def test_noise_injection_std_and_fresh_draws(delta):
    flow_stage, encdec_stage, emu_stage = _stages(delta)
    g = torch.Generator().manual_seed(1)
    for stage in (flow_stage, encdec_stage):
        scale = stage.model.y_scaler.std.double()
        stage.begin_epoch(g)
        eta1 = (stage.y_epoch.double() - stage.y_tr.double()) * scale  # back to physical units
        assert np.allclose(eta1.std(0).numpy(), delta * noise_std(), rtol=0.03)
        assert np.all(np.abs(eta1.mean(0).numpy()) < 0.05 * delta * noise_std())
        stage.begin_epoch(g)
        eta2 = (stage.y_epoch.double() - stage.y_tr.double()) * scale
        assert not torch.allclose(eta1, eta2)  # a fresh draw every epoch
        assert abs(np.corrcoef(eta1[:, 0], eta2[:, 0])[0, 1]) < 0.05
    # the test split gets one fixed noise draw, the re-evaluation target is the noisy y'
    assert not torch.equal(flow_stage.y_te, torch.as_tensor(np.random.default_rng(5).normal(size=(20_000, 16))[:10]).float())
    # never for the emulator
    emu_stage.begin_epoch(g)
    assert emu_stage.y_epoch is emu_stage.y_tr


def test_zero_noise_is_clean():
    flow_stage, encdec_stage, _ = _stages(0.0)
    g = torch.Generator().manual_seed(2)
    state = g.get_state()
    flow_stage.begin_epoch(g)
    assert torch.equal(flow_stage.y_epoch, flow_stage.y_tr)
    assert torch.equal(g.get_state(), state)  # no random numbers consumed
    encdec_stage.begin_epoch(g)
    assert torch.equal(encdec_stage.y_epoch, encdec_stage.y_tr)
    assert encdec_stage.eps_epoch.shape == (20_000, 3)


# ----------------------------------------------------------------------------- resume / seeding
def _state(path):
    return torch.load(path, weights_only=True)["state_dict"]


def _assert_same_weights(a, b):
    sa, sb = _state(a), _state(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


class _Killed(RuntimeError):
    pass


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
                  checkpoint_every=2, **extra, **_paths(d, "m"), **kw)

    full = run(tmp_path / "full")
    assert full["completed"]

    # 1) stopped cleanly after 3 epochs, then rerun
    part = run(tmp_path / "split", max_epochs_this_run=3)
    assert part == {**part, "completed": False, "epochs_done": 3}
    assert not (tmp_path / "split" / "m.pt").exists() and (tmp_path / "split" / "m.pt.ckpt").exists()
    assert run(tmp_path / "split")["completed"]
    _assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "split" / "m.pt")

    # 2) killed in the middle of epoch 6 (last checkpoint: epoch 4), then rerun
    cls = {"emulator": EmulatorStage, "flow": FlowStage, "encoder_decoder": EncoderDecoderStage}[stage]
    original = cls.batch_loss
    calls = {"n": 0}
    batches_per_epoch = 400 // hyper["batch_size"] + (400 % hyper["batch_size"] >= 2)

    def dying(self, idx):
        calls["n"] += 1
        if calls["n"] > 5 * batches_per_epoch + 2:
            raise _Killed
        return original(self, idx)

    monkeypatch.setattr(cls, "batch_loss", dying)
    with pytest.raises(_Killed):
        run(tmp_path / "killed")
    monkeypatch.setattr(cls, "batch_loss", original)
    assert len(pd.read_csv(tmp_path / "killed" / "m.csv")) == 5
    assert torch.load(tmp_path / "killed" / "m.pt.ckpt", weights_only=True)["epoch"] == 4
    assert run(tmp_path / "killed")["completed"]
    _assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "killed" / "m.pt")
    a = pd.read_csv(tmp_path / "full" / "m.csv").drop(columns=["seconds", "cpu_seconds"])
    b = pd.read_csv(tmp_path / "killed" / "m.csv").drop(columns=["seconds", "cpu_seconds"])
    pd.testing.assert_frame_equal(a, b)

    # 3) a finished run rerun with the same arguments only re-writes the outputs
    assert run(tmp_path / "full")["epochs_done"] == 7
    _assert_same_weights(tmp_path / "full" / "m.pt", tmp_path / "killed" / "m.pt")


def test_changed_hyper_ignores_checkpoint(data, tmp_path):
    kw = dict(seed=1, device="cpu", progress=False, **_paths(tmp_path, "m"))
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 4}, max_epochs_this_run=2, **kw)
    res = tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 4, "lr": 1e-3}, **kw)
    assert res["completed"]
    df = pd.read_csv(tmp_path / "m.csv")
    assert df["epoch"].tolist() == [1, 2, 3, 4] and df["lr"].iloc[0] == 1e-3


def test_checkpoint_of_other_training_code_is_not_reused(data, tmp_path, monkeypatch):
    """A finished checkpoint is reused by the code that wrote it (nothing retrained) and never by
    other training code: a rerun after a code change retrains instead of re-saving old weights."""
    kw = dict(hyper=EMU | {"epochs": 3}, seed=1, device="cpu", progress=False, **_paths(tmp_path, "m"))
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 3
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 0
    real = fingerprint.training_code_digest()
    assert len(real) == 64 and real == fingerprint.training_code_digest()
    monkeypatch.setattr(fingerprint, "training_code_digest", lambda: "edited" + real[6:])
    assert tr.train_emulator(str(data[0]), str(data[1]), **kw)["epochs_this_run"] == 3


def test_training_code_digest_covers_the_training_rules_code_inputs():
    """Every source a training rule declares as its ``code`` input enters the checkpoints' digest."""
    from pathlib import Path

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
        _encdec_run(data, emulator, tmp_path, {"epochs": 4}, checkpoint_every=1)
    good = torch.load(tmp_path / "m.pt.ckpt", weights_only=True)
    failed = torch.load(tmp_path / "m.pt.ckpt.nonfinite", weights_only=True)
    assert good["epoch"] == 1 and failed["epoch"] == 2
    assert all(torch.isfinite(v).all() for v in good["model"].values())
    assert any(not torch.isfinite(v).all() for v in failed["model"].values())


def test_seed_controls_result(data, tmp_path):
    def run(name, seed):
        tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 2}, seed=seed, device="cpu",
                          progress=False, **_paths(tmp_path, name))
        return tmp_path / f"{name}.pt"

    _assert_same_weights(run("a", 7), run("b", 7))
    with pytest.raises(AssertionError):
        _assert_same_weights(run("c", 7), run("d", 8))


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
                                 **_paths(tmp_path, name))
    finally:
        if monkeypatch is not None:
            monkeypatch.undo()
    return _state(tmp_path / f"{name}.pt")


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
    kw = dict(seed=1, device="cpu", progress=False, **_paths(tmp_path, "m"))
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


# ----------------------------------------------------------------------------- restarts
_RESTARTS = {"epochs": 6, "restarts": 3, "restart_epochs": 2}


def _encdec_run(data, emulator, d, hyper, checkpoint_every=2, **kw):
    d.mkdir(exist_ok=True)
    return tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                    hyper=ENCDEC | hyper, seed=3, noise_level=0.25, device="cpu", progress=False,
                                    checkpoint_every=checkpoint_every, **_paths(d, "m"), **kw)


def _drop_timing(df):
    return df.drop(columns=["seconds", "cpu_seconds"]).reset_index(drop=True)


def test_restarts_continue_the_candidate_with_the_lowest_test_loss(data, emulator, tmp_path):
    assert _encdec_run(data, emulator, tmp_path / "r", _RESTARTS)["completed"]
    info = torch.load(tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]
    seeds = [seeding.candidate_seed(3, c) for c in range(3)]
    assert info["seeds"] == seeds and seeds[0] == 3 and len(set(seeds)) == 3 and info["epochs"] == 2
    # each candidate's own losses file holds the score it was chosen by
    cand = [pd.read_csv(tmp_path / "r" / f"m.pt.ckpt.candidate{c}.csv") for c in range(3)]
    assert [df["epoch"].tolist() for df in cand] == [[1, 2]] * 3
    assert info["test_loss"] == [float(df["test_loss"].iloc[-1]) for df in cand]
    assert len(set(info["test_loss"])) == 3  # different initializations
    assert info["chosen"] == int(np.argmin(info["test_loss"]))
    # the run's history starts with the chosen candidate's epochs and goes on to the end
    run = pd.read_csv(tmp_path / "r" / "m.csv")
    assert run["epoch"].tolist() == list(range(1, 7))
    pd.testing.assert_frame_equal(_drop_timing(run.iloc[:2]), _drop_timing(cand[info["chosen"]]))
    # candidate 0 is the run without restarts, stopped at the choice
    _encdec_run(data, emulator, tmp_path / "plain", {"epochs": 6}, max_epochs_this_run=2)
    a = torch.load(tmp_path / "plain" / "m.pt.ckpt", weights_only=True)["model"]
    b = torch.load(tmp_path / "r" / "m.pt.ckpt.candidate0", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)

    # interrupted during the second candidate, then rerun: the same choice and weights
    part = _encdec_run(data, emulator, tmp_path / "split", _RESTARTS, max_epochs_this_run=3)
    assert not part["completed"] and not (tmp_path / "split" / "m.pt.ckpt").exists()
    assert torch.load(tmp_path / "split" / "m.pt.ckpt.candidate1", weights_only=True)["epoch"] == 1
    assert _encdec_run(data, emulator, tmp_path / "split", _RESTARTS)["completed"]
    _assert_same_weights(tmp_path / "r" / "m.pt", tmp_path / "split" / "m.pt")
    assert torch.load(tmp_path / "split" / "m.pt", weights_only=True)["info"]["restart"] == info


def _candidate_job(data, emulator, d, c, **kw):
    """Candidate ``c`` as the workflow's job of its own trains it: its checkpoint and losses given."""
    d.mkdir(exist_ok=True)
    ckpt = d / f"m.pt.ckpt.candidate{c}"
    return tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                    model=str(d / "m.pt"), losses=f"{ckpt}.csv", checkpoint=str(ckpt),
                                    hyper=ENCDEC | _RESTARTS, seed=3, noise_level=0.25, device="cpu",
                                    progress=False, checkpoint_every=2, candidate=c, **kw)


def test_candidates_trained_as_jobs_of_their_own_give_the_same_run_and_are_only_read(data, emulator, tmp_path):
    """The workflow trains each restart candidate in a job of its own, side by side, and hands the
    run their checkpoints: the run is bit-identical to one that trains them itself, and leaves
    its inputs (the candidates' files) untouched."""
    assert _encdec_run(data, emulator, tmp_path / "r", _RESTARTS)["completed"]
    jobs = tmp_path / "jobs"
    for c in (2, 0, 1):  # any order
        res = _candidate_job(data, emulator, jobs, c)
        assert res["epochs_done"] == 2 and not (jobs / "m.pt").exists() and not (jobs / "m.pt.ckpt").exists()
        assert res["score"] == float(pd.read_csv(f"{jobs}/m.pt.ckpt.candidate{c}.csv")["test_loss"].iloc[-1])
    files = sorted(jobs.iterdir())
    before = {f: (f.stat().st_mtime_ns, f.read_bytes()) for f in files}
    again = _candidate_job(data, emulator, jobs, 1)  # a finished candidate is not retrained
    assert again["epochs_this_run"] == 0 and again["score"] == torch.load(
        tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]["test_loss"][1]
    assert _encdec_run(data, emulator, jobs, _RESTARTS,
                       candidates=[str(jobs / f"m.pt.ckpt.candidate{c}") for c in range(3)])["completed"]
    assert {f: (f.stat().st_mtime_ns, f.read_bytes()) for f in files} == before
    _assert_same_weights(tmp_path / "r" / "m.pt", jobs / "m.pt")
    info = [torch.load(d / "m.pt", weights_only=True)["info"]["restart"] for d in (tmp_path / "r", jobs)]
    assert info[0] == info[1]
    pd.testing.assert_frame_equal(_drop_timing(pd.read_csv(tmp_path / "r" / "m.csv")),
                                  _drop_timing(pd.read_csv(jobs / "m.csv")))


def test_a_candidate_continued_under_a_shorter_schedule_resumes_at_the_choice(data, emulator, tmp_path):
    """benchmarks/continuation_epochs.py: the chosen candidate's checkpoint, given the fingerprint
    of a run with fewer epochs (:func:`~cvsim6.training.train.encoder_decoder_fingerprint`, the
    one that run's checkpoints hold), is resumed at the choice epoch and trained to the end."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("continuation_epochs", ROOT / "benchmarks" / "continuation_epochs.py")
    ce = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ce)
    hyper = ENCDEC | _RESTARTS | {"epochs": 8, "lr_schedule": "cosine", "warmup_epochs": 0, "lr_final": 0.1}
    d = tmp_path / "run"
    d.mkdir()
    ckpt = d / "m.pt.ckpt.candidate1"
    tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                             model=str(d / "m.pt"), losses=f"{ckpt}.csv", checkpoint=str(ckpt), hyper=hyper, seed=3, device="cpu",
                             progress=False, candidate=1)
    restart = {"chosen": 1, "epochs": 2}
    job = (5, tmp_path / "e5", data[0].parent, emulator[0] / "emulator.pt", hyper, 3, ckpt, restart)
    assert ce.continue_candidate(job)[0::2] == (5, 3)  # epochs 3-5 trained here
    out = tmp_path / "e5"
    losses = pd.read_csv(out / "encoder_decoder_delta0_losses.csv")
    assert losses["epoch"].tolist() == [1, 2, 3, 4, 5]
    pd.testing.assert_frame_equal(_drop_timing(losses.iloc[:2]), _drop_timing(pd.read_csv(f"{ckpt}.csv")))
    def cosine(epoch, total):  # warmup 0, lr_final 0.1 (optimization.make_scheduler)
        return hyper["lr"] * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * epoch / (total - 1))))

    # epoch 3 at the rate the 8-epoch cosine set after epoch 2 (restored with the optimizer), then the 5-epoch one
    assert losses["lr"].iloc[2:].tolist() == pytest.approx([cosine(2, 8), cosine(3, 5), cosine(4, 5)])
    assert losses["lr"].iloc[-1] == pytest.approx(0.1 * hyper["lr"])
    saved = torch.load(out / "models" / "encoder_decoder_delta0.pt", weights_only=True)["info"]
    assert saved["epochs_done"] == 5 and saved["restart"] == restart
    # the fingerprint is the one a 5-epoch run writes, and differs from the 8-epoch run's
    splits = (*load_split(str(data[0])), *load_split(str(data[1])))
    fp5 = tr.encoder_decoder_fingerprint(hp.check_hyper("encoder_decoder", hyper | {"epochs": 5}), 3, 0.0, splits,
                                         str(emulator[0] / "emulator.pt"))
    assert torch.load(out / "models" / "encoder_decoder_delta0.pt.ckpt", weights_only=True)["fingerprint"] == fp5
    assert torch.load(ckpt, weights_only=True)["fingerprint"].split(":")[0] != fp5
    assert ce.continue_candidate(job)[0::2] == (5, 0)  # a rerun reads the finished continuation


def test_candidate_options_are_checked(data, emulator, tmp_path):
    with pytest.raises(ValueError, match="candidate 3 is not one of the 3"):
        _candidate_job(data, emulator, tmp_path, 3)
    with pytest.raises(ValueError, match="candidate 0 is not one of the 1"):
        _encdec_run(data, emulator, tmp_path, {"epochs": 6}, candidate=0, checkpoint=str(tmp_path / "c"))
    with pytest.raises(ValueError, match="losses at checkpoint"):
        _encdec_run(data, emulator, tmp_path, _RESTARTS, candidate=0, checkpoint=str(tmp_path / "c"))
    with pytest.raises(ValueError, match="2 candidate checkpoints given for restarts: 3"):
        _encdec_run(data, emulator, tmp_path, _RESTARTS, candidates=["a", "b"])
    assert not list(tmp_path.glob("*.ckpt*")) and not (tmp_path / "m.pt").exists()


def test_a_diverged_candidate_loses_and_is_not_replayed(data, emulator, tmp_path, monkeypatch):
    real_fit, calls = loop.fit, []

    def fit(stage, hyper, seed, *args, **kw):
        calls.append(seed)
        if seed == seeding.candidate_seed(3, 1):
            raise FloatingPointError("non-finite loss at epoch 1")
        return real_fit(stage, hyper, seed, *args, **kw)

    monkeypatch.setattr(loop, "fit", fit)
    res = _encdec_run(data, emulator, tmp_path, _RESTARTS, max_epochs_this_run=4)  # candidates 0, 2 to the choice
    assert not res["completed"] and calls == [seeding.candidate_seed(3, c) for c in range(3)] + [3]  # + the run, 0 epochs
    assert torch.load(tmp_path / "m.pt.ckpt.candidate1", weights_only=True)["diverged"]
    calls.clear()
    assert _encdec_run(data, emulator, tmp_path, _RESTARTS)["completed"]
    assert calls == [3]  # the run goes on from the chosen candidate; candidate 1 is not replayed
    info = torch.load(tmp_path / "m.pt", weights_only=True)["info"]["restart"]
    assert info["test_loss"][1] == float("inf") and info["chosen"] in (0, 2)
    assert info["chosen"] == (0 if info["test_loss"][0] <= info["test_loss"][2] else 2)


def test_restarts_that_tie_continue_candidate_0_exactly_as_a_run_without_them(data, emulator, tmp_path,
                                                                               monkeypatch):
    monkeypatch.setattr(restarts, "candidate_seed", lambda seed, c: seed)  # three identical candidates
    assert _encdec_run(data, emulator, tmp_path / "r", _RESTARTS)["completed"]
    info = torch.load(tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]
    assert info["chosen"] == 0 and len(set(info["test_loss"])) == 1
    assert _encdec_run(data, emulator, tmp_path / "plain", {"epochs": 6})["completed"]
    _assert_same_weights(tmp_path / "plain" / "m.pt", tmp_path / "r" / "m.pt")
    pd.testing.assert_frame_equal(_drop_timing(pd.read_csv(tmp_path / "plain" / "m.csv")),
                                  _drop_timing(pd.read_csv(tmp_path / "r" / "m.csv")))


def test_choose_candidate_prefers_those_that_meet_the_target():
    loss = [3.0, 1.0, 2.0, 1.0]
    assert restarts.choose_candidate(loss, [None] * 4, None) == 1  # lowest loss, ties to the lower index
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.01, 0.02], None) == 1  # no target: loss only
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.01, 0.02], 0.05) == 3  # lowest loss among 2 and 3
    assert restarts.choose_candidate(loss, [0.01, 0.4, 0.5, 0.4], 0.05) == 0  # the only one, despite its loss
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.3, 0.2], 0.05) == 1  # none meets it: loss among all
    assert restarts.choose_candidate([math.inf, 2.0], [0.01, 0.5], 0.05) == 0  # inf worst: diverged never meets
    assert restarts.choose_candidate([math.inf, 2.0], [math.inf, 0.5], 0.05) == 1
    assert restarts.meets_target([None, 0.05], 0.05) and not restarts.meets_target([0.05], None)


def test_reconstruction_errors_of_a_decoder_that_returns_zero_are_the_test_parameters_second_moments(
        data, emulator, monkeypatch):
    """Per parameter, the mean over every test row (taken in chunks) of the squared standardized
    value, computed here by numpy from the parquet file and the fitted scaler."""
    monkeypatch.setattr(stages, "EVAL_CHUNK", 7)  # 100 test rows: 15 chunks, the last one short
    v_tr, y_tr = load_split(str(data[0]))
    v_te, y_te = load_split(str(data[1]))
    net = nw.EncoderDecoder(latent_dim=7, encoder_hidden=16, encoder_layers=3, decoder_hidden=32, decoder_layers=3)
    net.x_scaler.fit(v_tr)
    net.y_scaler.fit(y_tr)
    emu = nw.load_model(str(emulator[0] / "emulator.pt"))
    stage = EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                                net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), 0.25,
                                hp.check_hyper("encoder_decoder", ENCDEC), torch.Generator().manual_seed(0),
                                torch.device("cpu"))
    monkeypatch.setattr(net, "decode", lambda y, w: torch.zeros(len(y), 23, dtype=y.dtype))
    expected = (((v_te - net.x_scaler.mean.double().numpy()) / net.x_scaler.std.double().numpy()) ** 2).mean(axis=0)
    got = stage.reconstruction_errors().numpy()
    assert got.shape == (23,)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert (got > 0.5).all()  # test rows of the training range: each about its variance


_SCREEN = _RESTARTS | {"restart_target": 0.1, "max_restarts": 6}


def _screen(data, emulator, d, worst, monkeypatch, hyper=_SCREEN, **kw):
    """A run whose candidate c has worst reconstruction MSE ``worst[c]`` (by design)."""
    calls = []

    def fake(make_stage, seed, c, path):
        calls.append(c)
        assert path.exists()
        return worst[c]

    monkeypatch.setattr(restarts, "worst_reconstruction", fake)
    res = _encdec_run(data, emulator, d, hyper, **kw)
    if not res["completed"]:
        return None, calls
    return torch.load(d / "m.pt", weights_only=True)["info"]["restart"], calls


def test_screening_goes_on_until_a_candidate_meets_the_target(data, emulator, tmp_path, monkeypatch):
    info, calls = _screen(data, emulator, tmp_path / "met", [0.5, 0.4, 0.3, 0.6, 0.05, 0.01], monkeypatch)
    assert calls == [0, 1, 2, 3, 4]  # stops at the first that meets it: candidate 5 never trained
    assert not (tmp_path / "met" / "m.pt.ckpt.candidate5").exists()
    assert (tmp_path / "met" / "m.pt.ckpt.candidate4").exists()
    assert info["chosen"] == 4 and info["target"] == 0.1 and info["worst_reconstruction"] == [0.5, 0.4, 0.3, 0.6, 0.05]
    assert info["seeds"] == [seeding.candidate_seed(3, c) for c in range(5)] and len(info["test_loss"]) == 5
    # the run goes on from candidate 4: its history starts with that candidate's epochs
    run = pd.read_csv(tmp_path / "met" / "m.csv")
    cand = pd.read_csv(tmp_path / "met" / "m.pt.ckpt.candidate4.csv")
    pd.testing.assert_frame_equal(_drop_timing(run.iloc[:2]), _drop_timing(cand))
    # interrupted while screening candidate 4, then rerun: the same choice and weights
    worst = [0.5, 0.4, 0.3, 0.6, 0.05, 0.01]
    part, calls = _screen(data, emulator, tmp_path / "split", worst, monkeypatch, max_epochs_this_run=9)
    assert part is None and calls == [0, 1, 2, 3]
    assert torch.load(tmp_path / "split" / "m.pt.ckpt.candidate4", weights_only=True)["epoch"] == 1
    again, calls = _screen(data, emulator, tmp_path / "split", worst, monkeypatch)
    assert calls == [0, 1, 2, 3, 4] and again == info
    _assert_same_weights(tmp_path / "met" / "m.pt", tmp_path / "split" / "m.pt")
    # none meets it: all max_restarts screened, the lowest test loss continues
    info, calls = _screen(data, emulator, tmp_path / "none", [0.5] * 6, monkeypatch)
    assert calls == list(range(6)) and info["chosen"] == int(np.argmin(info["test_loss"]))
    # one of the first restarts meets it: nothing more is screened, the choice as without a target
    info, calls = _screen(data, emulator, tmp_path / "first", [0.5, 0.01, 0.01, 0.0, 0.0, 0.0], monkeypatch)
    assert calls == [0, 1, 2] and len(info["test_loss"]) == 3
    losses = info["test_loss"]
    assert info["chosen"] == (1 if losses[1] <= losses[2] else 2)


def test_hyper_validation():
    with pytest.raises(ValueError, match="missing"):
        hp.check_hyper("emulator", {k: v for k, v in EMU.items() if k != "lr"})
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("flow", FLOW | {"hiden": 3})
    with pytest.raises(ValueError, match="reduction"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"reduction": "max"})
    with pytest.raises(ValueError, match="lr_step"):
        hp.check_hyper("emulator", {k: v for k, v in EMU.items() if k != "lr_step"})
    with pytest.raises(ValueError, match="reeval_target"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"reeval_target": "exact"})
    with pytest.raises(ValueError, match="dtype"):
        hp.check_hyper("emulator", EMU | {"dtype": "float16"})
    with pytest.raises(ValueError, match="warmup_epochs"):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "cosine", "warmup_epochs": EMU["epochs"]})
    for bad in (0.0, -1e-3, True, "1e-3", float("nan")):
        with pytest.raises(ValueError, match="variance_floor"):
            hp.check_hyper("emulator", EMU | {"variance_floor": bad})
    with pytest.raises(ValueError, match="unknown"):  # an emulator option only
        hp.check_hyper("flow", FLOW | {"variance_floor": 1e-3})
    for bad in (-0.1, 1.5, True, "0.5", float("nan"), None):
        with pytest.raises(ValueError, match=f"relative_weight must be a number in \\[0, 1\\], got {re.escape(repr(bad))}"):
            hp.check_hyper("emulator", EMU | {"relative_weight": bad})
    for key in ("linear_skip", "log_inputs"):
        for bad in (1, "true", None):
            with pytest.raises(ValueError, match=f"{key} must be true or false, got {re.escape(repr(bad))}"):
                hp.check_hyper("emulator", EMU | {key: bad})
        with pytest.raises(ValueError, match="unknown"):
            hp.check_hyper("flow", FLOW | {key: True})
    assert hp.check_hyper("emulator", EMU)["relative_weight"] == 0.0
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"relative_weight": 0.5})
    for bad in (-1, 2.5, ENCDEC["epochs"] + 1):
        with pytest.raises(ValueError, match="kl_warmup_epochs"):
            hp.check_hyper("encoder_decoder", ENCDEC | {"kl_warmup_epochs": bad})
    for bad in (0, -1.0, True, "4", float("inf")):
        with pytest.raises(ValueError, match=f"logvar_max must be null or a number > 0, got {re.escape(repr(bad))}"):
            hp.check_hyper("encoder_decoder", ENCDEC | {"logvar_max": bad})
    assert hp.check_hyper("encoder_decoder", ENCDEC)["logvar_max"] is None
    for bad in ({"restarts": 0}, {"restarts": 2}, {"restarts": 2, "restart_epochs": ENCDEC["epochs"]},
                {"restarts": 2, "restart_epochs": 5, "eval_every": 2}):
        with pytest.raises(ValueError, match="restart"):
            hp.check_hyper("encoder_decoder", ENCDEC | bad)
    for bad in ({"restart_target": 0.1}, {"restart_target": 0.1, "max_restarts": 2} | _RESTARTS,
                {"max_restarts": 6} | _RESTARTS, {"restart_target": 0.0} | _RESTARTS):
        with pytest.raises(ValueError, match="restart_target"):
            hp.check_hyper("encoder_decoder", ENCDEC | bad)
    assert hp.check_hyper("encoder_decoder", ENCDEC | _SCREEN)["max_restarts"] == 6
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("emulator", EMU | {"restart_target": 0.1})
    h = hp.check_hyper("emulator", EMU)
    assert h["restarts"] == 1
    assert h["weight_decay"] == 0.0 and h["grad_clip"] == 0.0
    assert h["lr_schedule"] == "step" and h["eval_every"] == 1 and not h["keep_best"] and h["dtype"] == "float32"
    # the cosine schedule needs no step parameters
    cos = {k: v for k, v in EMU.items() if k not in ("lr_step", "lr_gamma")} | {"lr_schedule": "cosine"}
    assert hp.check_hyper("emulator", cos)["lr_schedule"] == "cosine"


def test_hyper_defaults_are_read_from_the_schema(tmp_path, monkeypatch):
    """The defaults are the schema's: values, types and key order as the model files record them;
    a default edited in the schema is the one training uses."""
    from cvsim6.workflow import config

    h = hp.check_hyper("encoder_decoder", ENCDEC)
    assert list(h) == ["weight_decay", "grad_clip", "lr_schedule", "lr_step", "lr_gamma", "warmup_epochs", "lr_final",
                       "eval_every", "keep_best", "dtype", "restarts", "restart_epochs", "reduction", "activation",
                       "reeval_target", "noisy_scaling", "kl_warmup_epochs", "restart_target", "max_restarts",
                       "logvar_max", "log_parameters",
                       "beta_prior", "latent_dim", "encoder_hidden", "encoder_layers", "decoder_hidden",
                       "decoder_layers", "beta_d", "beta_v", "beta_r", "epochs", "batch_size", "lr"]
    assert h["lr_step"] == 10 and h["reduction"] == "sum" and h["beta_prior"] == 0.0
    assert type(h["weight_decay"]) is float and type(h["warmup_epochs"]) is int
    edited = config.SCHEMA_PATH.read_text().replace(
        "weight_decay: {description: Adam L2 penalty (0 = off)., type: number, minimum: 0, default: 0.0}",
        "weight_decay: {description: Adam L2 penalty (0 = off)., type: number, minimum: 0, default: 2.5e-4}")
    assert edited != config.SCHEMA_PATH.read_text()
    (tmp_path / "schema.yaml").write_text(edited)
    monkeypatch.setattr(config, "SCHEMA_PATH", tmp_path / "schema.yaml")
    assert hp.check_hyper("flow", FLOW)["weight_decay"] == 1e-5  # given: kept
    assert hp.check_hyper("emulator", EMU)["weight_decay"] == 2.5e-4


def test_hyper_errors_name_the_stage_key_and_value():
    with pytest.raises(ValueError, match=re.escape("flow hyperparameters: missing [], unknown ['hiden', 'lr_decay']")):
        hp.check_hyper("flow", FLOW | {"hiden": 3, "lr_decay": 0.5})
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter batch_size must be an integer >= 2, got 1")):
        hp.check_hyper("emulator", EMU | {"batch_size": 1})
    with pytest.raises(ValueError, match=re.escape("flow hyperparameter lr_gamma must be null or a number in (0, 1], "
                                                   "got 1.5")):
        hp.check_hyper("flow", FLOW | {"lr_gamma": 1.5})
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter lr_schedule must be one of 'step', "
                                                   "'cosine', got 'linear'")):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "linear"})
    # the rules that tie keys together
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter warmup_epochs must be below epochs (25), "
                                                   "got 25")):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "cosine", "warmup_epochs": 25})
    with pytest.raises(ValueError, match=re.escape("encoder_decoder hyperparameter kl_warmup_epochs must be at most "
                                                   "epochs (25), got 26")):
        hp.check_hyper("encoder_decoder", ENCDEC | {"kl_warmup_epochs": 26})
    with pytest.raises(ValueError, match=re.escape("flow: lr_schedule 'step' needs lr_step and lr_gamma, got 20, None")):
        hp.check_hyper("flow", {k: v for k, v in FLOW.items() if k != "lr_gamma"})
    with pytest.raises(ValueError, match=re.escape("flow hyperparameter restart_epochs must be an integer in [1, epochs)"
                                                   " and a multiple of eval_every (4) when restarts > 1, got 6")):
        hp.check_hyper("flow", FLOW | {"restarts": 2, "restart_epochs": 6, "eval_every": 4})
    assert hp.check_hyper("flow", FLOW | {"restarts": 2, "restart_epochs": 8, "eval_every": 4})["restarts"] == 2


# ----------------------------------------------------------------------------- schedules and options
def test_cosine_schedule_learning_rates(data, tmp_path):
    h = {k: v for k, v in EMU.items() if k not in ("lr_step", "lr_gamma")}
    h |= {"epochs": 12, "lr_schedule": "cosine", "warmup_epochs": 3, "lr_final": 0.1}
    tr.train_emulator(str(data[0]), str(data[1]), hyper=h, seed=0, device="cpu", progress=False,
                      **_paths(tmp_path, "m"))
    lr = pd.read_csv(tmp_path / "m.csv")["lr"].to_numpy() / h["lr"]
    # linear warm-up to the full rate, then a cosine from 1 down to lr_final in the last epoch
    np.testing.assert_allclose(lr[:4], [0.25, 0.5, 0.75, 1.0], rtol=1e-12)
    np.testing.assert_allclose(lr[7], 0.1 + 0.9 * 0.5, rtol=1e-12)  # half-way: t = (7 - 3) / 8
    np.testing.assert_allclose(lr[-1], 0.1, rtol=1e-12)
    assert np.all(np.diff(lr[3:]) < 0)


def _emulator_test_mse(model_path, test_path):
    """Held-out MSE of a saved emulator in its standardized output space (the training's test loss)."""
    from cvsim6.data.datasets import load_split

    net = nw.load_model(model_path)
    v, y = load_split(str(test_path))
    with torch.no_grad():
        pred = net(net.x_scaler.transform(torch.tensor(v, dtype=torch.float32)))
        return float(nw.emulator_loss(pred, net.y_scaler.transform(torch.tensor(y, dtype=torch.float32))))


@pytest.mark.parametrize("keep_best", [True, False])
def test_eval_every_and_keep_best(keep_best, data, tmp_path):
    # a rate high enough that the held-out loss is not monotone over the epochs
    h = EMU | {"epochs": 15, "eval_every": 3, "keep_best": keep_best, "lr": 0.1, "lr_step": 100}
    res = tr.train_emulator(str(data[0]), str(data[1]), hyper=h, seed=4, device="cpu", progress=False,
                            **_paths(tmp_path, "m"))
    df = pd.read_csv(tmp_path / "m.csv")
    tested = df[np.isfinite(df["test_loss"])]
    assert tested["epoch"].tolist() == [3, 6, 9, 12, 15]  # every 3rd (and always the last)
    assert np.isfinite(df["train_loss"]).all() and (df["cpu_seconds"] > 0).all()
    best = tested.loc[tested["test_loss"].idxmin()]
    assert best["epoch"] != 15, "the test needs a run whose last evaluation is not its best"
    _, info = nw.load_model(tmp_path / "m.pt", with_info=True)
    saved = _emulator_test_mse(tmp_path / "m.pt", data[1])
    expected = best if keep_best else tested.iloc[-1]
    np.testing.assert_allclose(saved, expected["test_loss"], rtol=1e-5)
    assert res["test_loss"] == pytest.approx(expected["test_loss"], rel=1e-12)
    assert info["best_epoch"] == int(expected["epoch"])


def test_clean_reevaluation_target():
    rng = np.random.default_rng(6)
    v, y = rng.normal(size=(300, 23)), rng.normal(size=(300, 16))
    emu = nw.Emulator(hidden=8, layers=2)
    stages = {}
    for target in ("clean", "noisy"):
        torch.manual_seed(0)
        encdec = nw.EncoderDecoder(latent_dim=3, encoder_hidden=8, encoder_layers=2, decoder_hidden=8,
                                   decoder_layers=2)
        h = hp.check_hyper("encoder_decoder", ENCDEC | {"reeval_target": target, "beta_r": 1.0})
        st = EncoderDecoderStage(encdec, emu, v, y, v[:10], y[:10], 2.0, h, torch.Generator().manual_seed(1),
                                    torch.device("cpu"))
        st.begin_epoch(torch.Generator().manual_seed(2))
        stages[target] = st
    idx = torch.arange(64)
    for target, st in stages.items():
        with torch.no_grad():
            _, parts = st.batch_loss(idx)
            v_hat = st.model(st.v_tr[idx], st.y_epoch[idx], st.eps_epoch[idx])[0]
            want = st.y_tr[idx] if target == "clean" else st.y_epoch[idx]
            ref = ((st.reevaluate(v_hat) - want) ** 2).sum(dim=1).mean()  # reduction "sum"
            np.testing.assert_allclose(float(parts["reeval"]), float(ref), rtol=1e-6)
    # same decoder input y' and decoder term: only the re-evaluation target differs
    assert torch.equal(stages["clean"].y_epoch, stages["noisy"].y_epoch)
    with torch.no_grad():
        dc = stages["clean"].batch_loss(idx)[1]
        dn = stages["noisy"].batch_loss(idx)[1]
    assert float(dc["decoder"]) == float(dn["decoder"]) and float(dc["reeval"]) < float(dn["reeval"])


def test_a_logvar_cap_never_reached_trains_bit_for_bit_as_none(data, emulator, tmp_path):
    """The cap changes nothing below it: a training whose log-variances stay under it gives the
    uncapped run's losses and weights exactly; a cap the training reaches changes the run."""
    runs = {}
    for name, cap in (("none", None), ("high", 50.0), ("low", 0.01)):
        h = ENCDEC | {"epochs": 6} | ({} if cap is None else {"logvar_max": cap})
        tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"), hyper=h,
                                 seed=3, device="cpu", progress=False, **_paths(tmp_path, name))
        model, info = nw.load_model(tmp_path / f"{name}.pt", with_info=True)
        assert model.logvar_max == cap and info["hyper"]["logvar_max"] == cap
        runs[name] = (pd.read_csv(tmp_path / f"{name}.csv"), model.state_dict())
    cols = ["train_loss", "test_loss", "train_kl", "test_kl"]
    assert runs["high"][0][cols].equals(runs["none"][0][cols])
    assert all(torch.equal(runs["high"][1][k], v) for k, v in runs["none"][1].items())
    # the low cap binds: the untrained encoder's log-variances start near 0, above 0.01
    assert not runs["low"][0]["train_loss"].equals(runs["none"][0]["train_loss"])


@pytest.mark.parametrize("cap", [None, 4.0])
def test_logvar_cap_keeps_a_spiked_encoders_test_loss_finite(cap):
    """The failure of decision 0031: an encoder whose raw log-variance leaves float32's range for
    some rows. Uncapped, sigma = exp(logvar / 2) overflows and the test loss is not finite; capped,
    the test KL is the closed form at the cap and every term stays finite."""
    rng = np.random.default_rng(7)
    v, y = rng.normal(size=(40, 23)), rng.normal(size=(40, 16))
    torch.manual_seed(0)
    emu = nw.Emulator(hidden=8, layers=2)
    encdec = nw.EncoderDecoder(latent_dim=3, encoder_hidden=8, encoder_layers=2, decoder_hidden=8,
                               decoder_layers=2, logvar_max=cap)
    h = hp.check_hyper("encoder_decoder", ENCDEC | {"logvar_max": cap})
    st = EncoderDecoderStage(encdec, emu, v, y, v, y, 0.5, h, torch.Generator().manual_seed(1), torch.device("cpu"))
    last = encdec.encoder[-1]
    with torch.no_grad():
        last.weight[3:].zero_()  # rows 3..5 of the output are the log-variances
        last.bias[3:] = 200.0  # exp(100) overflows float32
    loss, parts = st.evaluate()
    if cap is None:
        assert not math.isfinite(loss)
        return
    assert math.isfinite(loss) and all(math.isfinite(p) for p in parts.values())
    with torch.no_grad():
        mu = encdec.encode(st.v_te)[0].double()
    closed_form = 0.5 * ((mu * mu).sum(1) + 3 * (math.exp(cap) - cap - 1.0)).mean()
    assert parts["kl"] == pytest.approx(float(closed_form), rel=1e-5)


def test_kl_warmup_ramps_the_training_kl_weight_only(data, emulator, tmp_path):
    """Training losses weigh the KL term by beta_v * e / k in epochs e = 1..k, then beta_v; the
    test losses (hence keep_best) always by the full beta_v."""
    h = ENCDEC | {"epochs": 6, "kl_warmup_epochs": 4, "beta_v": 0.5}
    tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"), hyper=h,
                             seed=0, noise_level=0.5, device="cpu", progress=False, **_paths(tmp_path, "m"))
    df = pd.read_csv(tmp_path / "m.csv")
    factor = np.array([0.25, 0.5, 0.75, 1.0, 1.0, 1.0])
    for split, f in (("train", factor), ("test", np.ones(6))):
        total = h["beta_d"] * df[f"{split}_decoder"] + h["beta_v"] * f * df[f"{split}_kl"] + h["beta_r"] * df[f"{split}_reeval"]
        np.testing.assert_allclose(df[f"{split}_loss"], total, rtol=1e-5)
    # the ramp is not a no-op: the full weight would give a different early training loss
    full = h["beta_d"] * df["train_decoder"] + h["beta_v"] * df["train_kl"] + h["beta_r"] * df["train_reeval"]
    assert not np.allclose(df["train_loss"][:3], full[:3], rtol=1e-3)


@pytest.mark.parametrize("delta", [0.0, 1.5])
def test_noisy_scaling_widens_the_output_standardizer(delta, data, emulator, tmp_path):
    from cvsim6.data.datasets import load_split

    _, y_tr = load_split(str(data[0]))
    clean_std = y_tr.std(axis=0)
    kw = dict(seed=0, device="cpu", progress=False, noise_level=delta)
    tr.train_flow(str(data[0]), str(data[1]), hyper=FLOW | {"epochs": 2, "noisy_scaling": True},
                  **_paths(tmp_path, "f"), **kw)
    tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                             hyper=ENCDEC | {"epochs": 2, "noisy_scaling": True}, **_paths(tmp_path, "e"), **kw)
    want = np.sqrt(clean_std ** 2 + (delta * noise_std()) ** 2)
    for name in ("f", "e"):
        net = nw.load_model(tmp_path / f"{name}.pt")
        np.testing.assert_allclose(net.y_scaler.std.double().numpy(), want, rtol=1e-6)
    # the encoder/decoder's re-evaluation converts between its scaling and the emulator's exactly
    encdec, emu = nw.load_model(tmp_path / "e.pt"), nw.load_model(emulator[0] / "emulator.pt")
    v_std = torch.randn(50, 23)
    with torch.no_grad():
        y_model = encdec.y_scaler.inverse(nw.make_reevaluator(emu, encdec)(v_std))
        y_emu = emu.predict(encdec.x_scaler.inverse(v_std))
    np.testing.assert_allclose(y_model.numpy(), y_emu.numpy(), rtol=1e-4, atol=1e-3)


def test_float64_follows_the_float32_run(data, tmp_path):
    kw = dict(seed=5, device="cpu", progress=False)
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 3}, **_paths(tmp_path, "s"), **kw)
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 3, "dtype": "float64"},
                      **_paths(tmp_path, "d"), **kw)
    single, double = _state(tmp_path / "s.pt"), _state(tmp_path / "d.pt")
    assert all(v.dtype == torch.float64 for k, v in double.items() if k.startswith("net."))
    for k in single:  # same initial weights, batches and updates: equal to float32 round-off
        np.testing.assert_allclose(double[k].double().numpy(), single[k].double().numpy(), rtol=1e-3, atol=1e-4)
    a, b = pd.read_csv(tmp_path / "s.csv"), pd.read_csv(tmp_path / "d.csv")
    np.testing.assert_allclose(b["test_loss"], a["test_loss"], rtol=1e-3)


def test_variance_floor_matrix_raises_only_the_small_variances():
    rng = np.random.default_rng(0)
    base = rng.normal(size=(5000, 4))
    y = np.c_[base, base[:, 0] + 0.01 * rng.normal(size=5000)]  # column 4 ~ column 0: one tiny direction
    y = (y - y.mean(0)) / y.std(0)
    c = np.cov(y, rowvar=False)
    lam = np.linalg.eigvalsh(c)
    assert lam[0] < 1e-4 < 0.5 < lam[1]
    floor = 1e-2
    w = loss_weights.variance_floor_matrix(y, floor)
    np.testing.assert_allclose(w, w.T, atol=1e-12)
    # the loss sees the covariance with its eigenvalues raised to the floor, the others unchanged
    np.testing.assert_allclose(np.linalg.eigvalsh(w @ c @ w), np.sort(np.maximum(lam, floor)), rtol=1e-9)
    # an error along a direction above the floor is left alone; along the tiny one, scaled by sqrt(floor/lam)
    vals, vecs = np.linalg.eigh(c)
    np.testing.assert_allclose(vecs[:, -1] @ w, vecs[:, -1], atol=1e-9)
    np.testing.assert_allclose(vecs[:, 0] @ w, np.sqrt(floor / vals[0]) * vecs[:, 0], rtol=1e-9, atol=1e-9)
    # a floor below every eigenvalue is the plain MSE
    np.testing.assert_allclose(loss_weights.variance_floor_matrix(y, lam[0] / 2), np.eye(5), atol=1e-9)
    with pytest.raises(ValueError, match="singular"):
        loss_weights.variance_floor_matrix(np.c_[y, y[:, 0]], floor)


def test_variance_floor_emulator_loss(data, tmp_path):
    """The loss is the MSE of the errors times W, the ``mse`` columns the plain MSE of the same
    weights; the identity matrix gives back the plain loss; the saved model is an ordinary emulator."""
    torch.manual_seed(0)
    net = nw.Emulator(16, 3)
    v, y = torch.randn(50, 23), torch.randn(50, 16)
    w = loss_weights.variance_floor_matrix(np.random.default_rng(1).normal(size=(200, 16)), 3.0)
    assert not np.allclose(w, np.eye(16))
    st = EmulatorStage(net, v, y, v, y, torch.device("cpu"), weighting=w)
    loss, parts = st.batch_loss(torch.arange(50))
    with torch.no_grad():
        err = net(v) - y
    assert float(loss.detach()) == pytest.approx(float(torch.mean((err @ torch.as_tensor(w, dtype=torch.float32)) ** 2)), rel=1e-5)
    with torch.no_grad():
        assert float(parts["mse"]) == pytest.approx(float(nw.emulator_loss(net(v), y)), rel=1e-6)
    plain = EmulatorStage(net, v, y, v, y, torch.device("cpu"), weighting=np.eye(16))
    assert float(plain.batch_loss(torch.arange(50))[0].detach()) == pytest.approx(float(parts["mse"]), rel=1e-6)

    hyper = EMU | {"epochs": 6, "variance_floor": 0.05}
    tr.train_emulator(str(data[0]), str(data[1]), hyper=hyper, seed=3, device="cpu", progress=False,
                      **_paths(tmp_path, "w"))
    df = pd.read_csv(tmp_path / "w.csv")
    assert {"train_mse", "test_mse"} <= set(df.columns)
    model, info = nw.load_model(tmp_path / "w.pt", with_info=True)
    assert isinstance(model, nw.Emulator) and info["hyper"]["variance_floor"] == 0.05
    test = pd.read_parquet(data[1])
    tv, ty = test[list(PARAMETER_NAMES)].to_numpy(), test[list(OUTPUT_NAMES)].to_numpy()
    err = (model.predict(tv) - ty) / model.y_scaler.std.double().numpy()
    assert df["test_mse"].iloc[-1] == pytest.approx((err ** 2).mean(), rel=1e-3)
    train = pd.read_parquet(data[0])
    wt = loss_weights.variance_floor_matrix(model.y_scaler.transform(train[list(OUTPUT_NAMES)].to_numpy()), 0.05)
    assert df["test_loss"].iloc[-1] == pytest.approx(((err @ wt) ** 2).mean(), rel=1e-3)


def test_relative_sample_weights_follow_the_inverse_squared_norm():
    """Weights ``(1 - a) + a (1/|y_i|^2) / mean_j(1/|y_train_j|^2)``: mean 1 over the training
    rows, ratios of the inverse squared norms at a = 1, ones at a = 0; a zero or non-finite row
    is named."""
    rng = np.random.default_rng(0)
    y_tr, y_te = rng.normal(size=(300, 16)) * 50 + 200, rng.normal(size=(40, 16)) * 50 + 200
    w = loss_weights.relative_sample_weights(y_tr, y_tr, 1.0)
    assert w.mean() == pytest.approx(1.0, rel=1e-12)
    n2 = (y_tr ** 2).sum(1)
    np.testing.assert_allclose(w[:5] / w[5:10], n2[5:10] / n2[:5], rtol=1e-12)
    np.testing.assert_array_equal(loss_weights.relative_sample_weights(y_tr, y_te, 0.0), np.ones(40))
    w_te, w_te1 = loss_weights.relative_sample_weights(y_tr, y_te, 0.25), loss_weights.relative_sample_weights(y_tr, y_te, 1.0)
    np.testing.assert_allclose(w_te, 0.75 + 0.25 * w_te1, rtol=1e-12)
    # the test rows use the training rows' normalization: a row equal to a training row weighs the same
    y_te[3] = y_tr[7]
    assert loss_weights.relative_sample_weights(y_tr, y_te, 1.0)[3] == pytest.approx(w[7], rel=1e-12)
    y_bad = y_te.copy()
    y_bad[11] = 0.0
    with pytest.raises(ValueError, match="row 11 of the given outputs has the squared norm 0.0"):
        loss_weights.relative_sample_weights(y_tr, y_bad, 1.0)
    y_bad[11] = np.nan
    with pytest.raises(ValueError, match="row 11 of the given outputs has the squared norm nan"):
        loss_weights.relative_sample_weights(y_tr, y_bad, 1.0)


def test_relative_weight_emulator_loss(data, tmp_path):
    """The stage's loss is the row-weighted mean of the squared standardized errors (with the
    variance floor: of the floored errors), the ``mse`` part the plain MSE; unit weights give back
    the plain loss. Trained with it, the losses CSV's test loss is that weighted MSE of the saved
    model on the test split, with weights from the physical outputs."""
    torch.manual_seed(0)
    net = nw.Emulator(16, 3)
    v, y = torch.randn(50, 23), torch.randn(50, 16)
    w = np.random.default_rng(2).uniform(0.1, 5.0, size=50)
    st = EmulatorStage(net, v, y, v, y, torch.device("cpu"), row_weights=(w, w))
    idx = torch.arange(10, 40)
    loss, parts = st.batch_loss(idx)
    with torch.no_grad():
        err = (net(v) - y).double().numpy()
    assert float(loss.detach()) == pytest.approx(float(np.mean(err[10:40] ** 2 * w[10:40, None])), rel=1e-5)
    assert float(parts["mse"]) == pytest.approx(float(np.mean(err[10:40] ** 2)), rel=1e-5)
    assert st.evaluate()[0] == pytest.approx(float(np.mean(err ** 2 * w[:, None])), rel=1e-5)
    ones = EmulatorStage(net, v, y, v, y, torch.device("cpu"), row_weights=(np.ones(50), np.ones(50)))
    assert float(ones.batch_loss(idx)[0].detach()) == pytest.approx(float(parts["mse"]), rel=1e-6)
    vf = loss_weights.variance_floor_matrix(np.random.default_rng(1).normal(size=(200, 16)), 3.0)
    both = EmulatorStage(net, v, y, v, y, torch.device("cpu"), weighting=vf, row_weights=(w, w))
    assert float(both.batch_loss(idx)[0].detach()) == pytest.approx(
        float(np.mean((err[10:40] @ vf) ** 2 * w[10:40, None])), rel=1e-5)

    hyper = EMU | {"epochs": 6, "relative_weight": 0.7}
    tr.train_emulator(str(data[0]), str(data[1]), hyper=hyper, seed=3, device="cpu", progress=False,
                      **_paths(tmp_path, "r"))
    df = pd.read_csv(tmp_path / "r.csv")
    model, info = nw.load_model(tmp_path / "r.pt", with_info=True)
    assert isinstance(model, nw.Emulator) and info["hyper"]["relative_weight"] == 0.7
    train, test = pd.read_parquet(data[0]), pd.read_parquet(data[1])
    tv, ty = test[list(PARAMETER_NAMES)].to_numpy(), test[list(OUTPUT_NAMES)].to_numpy()
    err = (model.predict(tv) - ty) / model.y_scaler.std.double().numpy()
    wt = loss_weights.relative_sample_weights(train[list(OUTPUT_NAMES)].to_numpy(), ty, 0.7)
    assert df["test_mse"].iloc[-1] == pytest.approx((err ** 2).mean(), rel=1e-3)
    assert df["test_loss"].iloc[-1] == pytest.approx((err ** 2 * wt[:, None]).mean(), rel=1e-3)
    assert df["test_loss"].iloc[-1] != pytest.approx(df["test_mse"].iloc[-1], rel=1e-3)


def test_resolve_device():
    assert optimization.resolve_device("cpu").type == "cpu"
    assert optimization.resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")

