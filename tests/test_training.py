"""Training (cvsim6.training): losses fall, noise injection, schedules and options."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from cvsim6 import nets as nw
from cvsim6.data.datasets import load_split
from cvsim6.training import loss_weights, optimization
from cvsim6.training import hyperparameters as hp
from cvsim6.training import train as tr
from cvsim6.training.stages import EmulatorStage, EncoderDecoderStage, FlowStage
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES, noise_std

from training_helpers import EMU, FLOW, ENCDEC, paths, state_dict


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
                            seed=0, device="cpu", progress=False, **paths(tmp_path, "emulator"))
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
                        progress=False, **paths(tmp_path, "flow"))
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
                                   **paths(tmp_path, "encdec"))
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
                                   device="cpu", progress=False, **paths(tmp_path, "encdec"))
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
                                   **paths(tmp_path, "encdec"))
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

    from cvsim6.workflow.config import load_config

    cfg = load_config(Path(__file__).parents[1] / "config" / config_file)
    shipped = cfg["training"]["studies"]["structural"]["encoder_decoder"]
    weights = {k: shipped[k] for k in ("beta_d", "beta_v", "beta_r", "reduction")}
    kl = {}
    for name, w in (("shipped", weights), ("literal", dict(beta_d=1, beta_v=2000, beta_r=20, reduction="sum"))):
        hyper = dict(ENCDEC, **w, epochs=30)
        tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                 hyper=hyper, seed=0, device="cpu", progress=False, **paths(tmp_path, name))
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


# ----------------------------------------------------------------------------- schedules and options
def test_cosine_schedule_learning_rates(data, tmp_path):
    h = {k: v for k, v in EMU.items() if k not in ("lr_step", "lr_gamma")}
    h |= {"epochs": 12, "lr_schedule": "cosine", "warmup_epochs": 3, "lr_final": 0.1}
    tr.train_emulator(str(data[0]), str(data[1]), hyper=h, seed=0, device="cpu", progress=False,
                      **paths(tmp_path, "m"))
    lr = pd.read_csv(tmp_path / "m.csv")["lr"].to_numpy() / h["lr"]
    # linear warm-up to the full rate, then a cosine from 1 down to lr_final in the last epoch
    np.testing.assert_allclose(lr[:4], [0.25, 0.5, 0.75, 1.0], rtol=1e-12)
    np.testing.assert_allclose(lr[7], 0.1 + 0.9 * 0.5, rtol=1e-12)  # half-way: t = (7 - 3) / 8
    np.testing.assert_allclose(lr[-1], 0.1, rtol=1e-12)
    assert np.all(np.diff(lr[3:]) < 0)


def _emulator_test_mse(model_path, test_path):
    """Held-out MSE of a saved emulator in its standardized output space (the training's test loss)."""

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
                            **paths(tmp_path, "m"))
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
                                 seed=3, device="cpu", progress=False, **paths(tmp_path, name))
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
                             seed=0, noise_level=0.5, device="cpu", progress=False, **paths(tmp_path, "m"))
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

    _, y_tr = load_split(str(data[0]))
    clean_std = y_tr.std(axis=0)
    kw = dict(seed=0, device="cpu", progress=False, noise_level=delta)
    tr.train_flow(str(data[0]), str(data[1]), hyper=FLOW | {"epochs": 2, "noisy_scaling": True},
                  **paths(tmp_path, "f"), **kw)
    tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                             hyper=ENCDEC | {"epochs": 2, "noisy_scaling": True}, **paths(tmp_path, "e"), **kw)
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
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 3}, **paths(tmp_path, "s"), **kw)
    tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU | {"epochs": 3, "dtype": "float64"},
                      **paths(tmp_path, "d"), **kw)
    single, double = state_dict(tmp_path / "s.pt"), state_dict(tmp_path / "d.pt")
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
                      **paths(tmp_path, "w"))
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
                      **paths(tmp_path, "r"))
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

