"""inVAErt networks (cvsim6.nets): sizes, Real-NVP bijectivity and log-det, losses, I/O."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from cvsim6 import nets as nw
from cvsim6.registry import N_OUTPUTS, N_PARAMETERS, noise_std



# ----------------------------------------------------------------------------- sizes
@pytest.mark.parametrize("hidden, expected", [(60, 24_376), (80, 42_096)])
def test_emulator_parameter_counts(hidden, expected):
    assert nw.count_parameters(nw.Emulator(hidden=hidden, layers=8)) == expected


def test_emulator_linear_skip_starts_as_the_plain_mlp_and_adds_a_linear_map():
    torch.manual_seed(5)
    plain = nw.Emulator(hidden=16, layers=3)
    torch.manual_seed(5)
    skip = nw.Emulator(hidden=16, layers=3, linear_skip=True)
    assert nw.count_parameters(skip) == nw.count_parameters(plain) + N_PARAMETERS * N_OUTPUTS + N_OUTPUTS
    v = torch.randn(30, N_PARAMETERS)
    with torch.no_grad():
        assert torch.equal(skip(v), plain(v))  # same MLP draws, skip zero at initialization
        a, b = torch.randn(N_OUTPUTS, N_PARAMETERS), torch.randn(N_OUTPUTS)
        skip.skip.weight.copy_(a)
        skip.skip.bias.copy_(b)
        assert torch.allclose(skip(v), plain(v) + v @ a.T + b, atol=1e-6)
        last = skip.net[-1]
        last.weight.zero_()
        last.bias.zero_()  # MLP silenced: the emulator is the linear map, exactly
        assert torch.allclose(skip(v), v @ a.T + b, atol=1e-6)
    # the skip learns along with the MLP
    skip.skip.weight.grad = None
    skip(v).pow(2).sum().backward()
    assert skip.skip.weight.grad.abs().sum() > 0


def test_emulator_log_inputs_features_and_floor():
    rng = np.random.default_rng(8)
    v = rng.uniform(0.5, 2.0, size=(200, N_PARAMETERS)) * np.abs(rng.normal(3.0, 1.0, N_PARAMETERS))
    v[:, 1] -= 20.0  # a negative column stays linear
    cols = [0, 2, 5]
    emu = nw.Emulator(hidden=8, layers=2, log_inputs=[5, 0, 2, 2])
    assert emu.config["log_inputs"] == cols
    emu.x_scaler.fit(v)
    emu.fit_features(v)
    assert np.allclose(emu.log_floor.numpy()[cols], 0.5 * v[:, cols].min(axis=0), rtol=1e-6)
    f = emu.features(torch.as_tensor(emu.x_scaler.transform(v), dtype=torch.float32)).double().numpy()
    expected = emu.x_scaler.transform(v)
    logs = np.log(v[:, cols])
    expected[:, cols] = (logs - logs.mean(axis=0)) / logs.std(axis=0)
    assert np.allclose(f, expected, atol=2e-5)
    # below the floor the logarithm continues as its tangent: continuous, same slope, finite at <= 0
    c = float(emu.log_floor[0])
    x = torch.tensor([c * 1.001, c, c * 0.999, 0.0, -c], dtype=torch.float64, requires_grad=True)
    phys = torch.as_tensor(v[:5].copy())
    g = emu.double()._log_features(torch.cat([x[:, None], phys[:, 1:]], dim=1))[:, 0]
    assert torch.allclose(g[:2], torch.log(x[:2]), rtol=0, atol=1e-12)
    assert g[2].item() == pytest.approx(math.log(c) - 0.001, abs=1e-12)  # tangent, not log: 5e-7 apart
    assert g[3].item() == pytest.approx(math.log(c) - 1.0) and g[4].item() == pytest.approx(math.log(c) - 2.0)
    g.sum().backward()
    assert np.allclose(x.grad.numpy(), [1 / (c * 1.001), 1 / c, 1 / c, 1 / c, 1 / c])
    with pytest.raises(ValueError, match="log_inputs column 1 has a training value <= 0"):
        nw.Emulator(hidden=8, layers=2, log_inputs=[1]).fit_features(v)
    with pytest.raises(ValueError, match="column indices"):
        nw.Emulator(hidden=8, layers=2, log_inputs=[N_PARAMETERS])


def test_encoder_decoder_parameter_counts():
    m = nw.EncoderDecoder(latent_dim=19, encoder_hidden=32, encoder_layers=6, decoder_hidden=64, decoder_layers=6)
    assert nw.count_parameters(m.encoder) == 6_246
    assert nw.count_parameters(m.decoder) == 20_439
    assert nw.count_parameters(m) == 6_246 + 20_439


@pytest.mark.parametrize("hidden, blocks, bn, expected", [(24, 16, False, 51_712), (18, 10, True, 20_280)])
def test_flow_parameter_counts(hidden, blocks, bn, expected):
    flow = nw.RealNVP(dim=16, hidden=hidden, blocks=blocks, layers_per_block=4, batchnorm=bn)
    assert nw.count_parameters(flow) == expected
    n_bn = sum(isinstance(m, nw.FlowBatchNorm) for m in flow.modules())
    assert n_bn == (blocks if bn else 0)


def test_mlp_structure():
    m = nw.MLP(5, 3, 7, 4)
    linears = [l for l in m if isinstance(l, nn.Linear)]
    assert len(linears) == 4
    assert isinstance(m[-1], nn.Linear)  # no output activation
    assert sum(isinstance(l, nn.SiLU) for l in m) == 3
    assert len([l for l in nw.MLP(5, 3, 7, 1) if isinstance(l, nn.Linear)]) == 1


def test_coupling_nets_activations():
    c = nw.RealNVP(hidden=8, blocks=2).layers[0]
    assert any(isinstance(l, nn.Tanh) for l in c.s) and not any(isinstance(l, nn.ReLU) for l in c.s)
    assert any(isinstance(l, nn.ReLU) for l in c.t) and not any(isinstance(l, nn.Tanh) for l in c.t)


# ----------------------------------------------------------------------------- Real-NVP
def _trained_bn_flow(batchnorm: bool, hidden: int, blocks: int) -> nw.RealNVP:
    torch.manual_seed(0)
    flow = nw.RealNVP(hidden=hidden, blocks=blocks, batchnorm=batchnorm).double()
    with torch.no_grad():  # non-trivial BatchNorm affine parameters
        for m in flow.modules():
            if isinstance(m, nw.FlowBatchNorm):
                m.log_gamma.uniform_(-0.3, 0.3)
                m.beta.uniform_(-0.5, 0.5)
    flow.train()
    g = torch.Generator().manual_seed(1)
    for _ in range(5):  # training-mode passes update the running statistics
        flow(2.0 * torch.randn(64, 16, generator=g, dtype=torch.float64) + 1.0)
    flow.eval()
    return flow


@pytest.mark.parametrize("batchnorm, hidden, blocks", [(False, 24, 16), (True, 18, 10)])
def test_flow_inverse_and_logdet(batchnorm, hidden, blocks):
    flow = _trained_bn_flow(batchnorm, hidden, blocks)
    if batchnorm:
        bn = next(m for m in flow.modules() if isinstance(m, nw.FlowBatchNorm))
        assert not torch.allclose(bn.running_mean, torch.zeros(16, dtype=torch.float64))
        assert not torch.allclose(bn.running_var, torch.ones(16, dtype=torch.float64))
    x = torch.randn(32, 16, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    with torch.no_grad():
        z, ld = flow(x)
        x2, ld_inv = flow.inverse(z)
    assert torch.allclose(x2, x, atol=1e-10)
    assert torch.allclose(ld + ld_inv, torch.zeros_like(ld), atol=1e-10)
    for i in range(3):
        jac = torch.autograd.functional.jacobian(lambda u: flow(u[None])[0][0], x[i])
        _, logabsdet = torch.linalg.slogdet(jac)
        assert logabsdet.item() == pytest.approx(ld[i].item(), abs=1e-8)
        jac_inv = torch.autograd.functional.jacobian(lambda u: flow.inverse(u[None])[0][0], z[i])
        assert torch.linalg.slogdet(jac_inv)[1].item() == pytest.approx(ld_inv[i].item(), abs=1e-8)


def test_flow_float32_roundtrip():
    torch.manual_seed(3)
    flow = nw.RealNVP(hidden=24, blocks=16).eval()
    x = torch.randn(100, 16)
    with torch.no_grad():
        assert torch.allclose(flow.inverse(flow(x)[0])[0], x, atol=1e-5)


def test_flow_batchnorm_modes():
    bn = nw.FlowBatchNorm(4, momentum=0.1)
    x = torch.randn(500, 4, generator=torch.Generator().manual_seed(4)) * 3.0 + 2.0
    bn.train()
    z, ld = bn(x)
    assert torch.allclose(z.mean(0), torch.zeros(4), atol=1e-5)  # batch statistics
    assert torch.allclose(z.std(0, unbiased=False), torch.ones(4), atol=1e-3)
    assert torch.allclose(bn.running_mean, 0.1 * x.mean(0), atol=1e-6)
    assert torch.allclose(bn.running_var, 0.9 + 0.1 * x.var(0), atol=1e-5)
    assert ld.shape == (500,)
    bn.eval()
    running = bn.running_mean.clone()
    z_eval, _ = bn(x)
    assert torch.equal(bn.running_mean, running)  # eval mode does not update
    assert torch.allclose(z_eval, (x - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps), atol=1e-6)
    assert torch.allclose(bn.inverse(z_eval)[0], x, atol=1e-4)


def test_flow_log_prob_and_sample():
    torch.manual_seed(5)
    flow = nw.RealNVP(hidden=8, blocks=4, batchnorm=True).eval()
    y = flow.sample(1000, torch.Generator().manual_seed(6))
    assert y.shape == (1000, 16) and torch.isfinite(y).all()
    assert torch.equal(y, flow.sample(1000, torch.Generator().manual_seed(6)))
    z, ld = flow(y)
    expected = torch.distributions.Normal(0.0, 1.0).log_prob(z).sum(1) + ld
    assert torch.allclose(flow.log_prob(y), expected, atol=1e-5)
    # physical density includes the standardization Jacobian
    flow.y_scaler.mean.fill_(3.0)
    flow.y_scaler.std.fill_(2.0)
    yp = flow.y_scaler.inverse(y[:10])
    lp = flow.log_prob_physical(yp.numpy())
    assert np.allclose(lp, flow.log_prob(y[:10]).detach().numpy() - 16 * np.log(2.0), atol=1e-4)


# ----------------------------------------------------------------------------- standardizer
def test_standardizer_numpy_and_torch():
    rng = np.random.default_rng(0)
    data = rng.normal(5.0, 3.0, size=(200, 4))
    data[:, 3] = 7.0  # constant column
    s = nw.Standardizer(4).fit(data)
    t = s.transform(data)
    assert np.allclose(t[:, :3].mean(0), 0.0, atol=1e-6) and np.allclose(t[:, :3].std(0), 1.0, atol=1e-6)
    assert np.allclose(t[:, 3], 0.0) and s.std[3] == 1.0
    assert np.allclose(s.inverse(t), data, atol=1e-5)
    tt = s.transform(torch.as_tensor(data))
    assert tt.dtype == torch.float64 and np.allclose(tt.numpy(), t)
    assert np.allclose(s.inverse(tt).numpy(), data, atol=1e-5)
    assert set(dict(s.named_buffers())) == {"mean", "std"} and nw.count_parameters(s) == 0


# ----------------------------------------------------------------------------- losses
def test_encoder_decoder_loss_matches_formula():
    torch.manual_seed(7)
    m = nw.EncoderDecoder(latent_dim=3, encoder_hidden=8, encoder_layers=2, decoder_hidden=8, decoder_layers=2)
    emu = nw.Emulator(hidden=8, layers=2)
    v, y, eps = torch.randn(10, 23), torch.randn(10, 16), torch.randn(10, 3)
    bd, bv, br = 1.5, 7.0, 3.0
    total, parts = nw.encoder_decoder_loss(m, v, y, eps, nw.make_reevaluator(emu, m), bd, bv, br, "sum")
    h = m.encoder(v)
    mu, logvar = h[:, :3], h[:, 3:]
    w = mu + eps * torch.exp(0.5 * logvar)
    vhat = m.decoder(torch.cat([y, w], 1))
    dec = ((v - vhat) ** 2).sum(1).mean()
    kl = (0.5 * (mu**2 + logvar.exp() - logvar - 1).sum(1)).mean()
    rec = ((y - emu(vhat)) ** 2).sum(1).mean()
    assert torch.allclose(total, bd * dec + bv * kl + br * rec)
    assert torch.allclose(parts["decoder"], dec) and torch.allclose(parts["kl"], kl)
    assert torch.allclose(parts["reeval"], rec)
    total_mse, parts_mse = nw.encoder_decoder_loss(m, v, y, eps, nw.make_reevaluator(emu, m), bd, bv, br, "mse")
    assert torch.allclose(parts_mse["decoder"], dec / 23) and torch.allclose(parts_mse["reeval"], rec / 16)
    assert torch.allclose(total_mse, bd * dec / 23 + bv * kl + br * rec / 16)
    assert nw.kl_divergence(torch.zeros(4, 3), torch.zeros(4, 3)).item() == 0.0


def test_prior_reevaluation_term_matches_formula_and_is_off_at_weight_zero():
    """beta_prior > 0 adds beta_prior * mean ||y_target - NN_e(NN_d(y', w_prior))||^2 to the
    paper's loss (one batch of 2N rows decoded, same values as decoding each half); at weight
    0 the loss is the paper's to the last bit."""
    torch.manual_seed(8)
    m = nw.EncoderDecoder(latent_dim=3, encoder_hidden=8, encoder_layers=2, decoder_hidden=8, decoder_layers=2)
    emu = nw.Emulator(hidden=8, layers=2)
    v, y, yc, eps, wp = torch.randn(10, 23), torch.randn(10, 16), torch.randn(10, 16), torch.randn(10, 3), \
        3.0 * torch.randn(10, 3)
    re = nw.make_reevaluator(emu, m)
    base, base_parts = nw.encoder_decoder_loss(m, v, y, eps, re, 1.5, 7.0, 3.0, "mse", y_target_std=yc)
    total, parts = nw.encoder_decoder_loss(m, v, y, eps, re, 1.5, 7.0, 3.0, "mse", y_target_std=yc,
                                           w_prior=wp, beta_prior=4.0)
    prior = ((yc - emu(m.decoder(torch.cat([y, wp], 1)))) ** 2).mean()
    assert torch.allclose(parts["prior_reeval"], prior) and prior > 0
    assert torch.allclose(total, base + 4.0 * prior)
    for k in ("decoder", "kl", "reeval"):
        assert torch.allclose(parts[k], base_parts[k])
    off, off_parts = nw.encoder_decoder_loss(m, v, y, eps, re, 1.5, 7.0, 3.0, "mse", y_target_std=yc,
                                             w_prior=wp, beta_prior=0.0)
    assert torch.equal(off, base) and "prior_reeval" not in off_parts
    # the gradient reaches the decoder through the prior half
    m.zero_grad()
    nw.encoder_decoder_loss(m, v, y, eps, re, 0.0, 0.0, 0.0, "mse", w_prior=wp, beta_prior=1.0)[0].backward()
    assert m.decoder[0].weight.grad.abs().sum() > 0 and all(
        p.grad is None or p.grad.abs().sum() == 0 for p in m.encoder.parameters())


def test_logvar_cap_bounds_the_value_and_passes_the_gradient_through(tmp_path):
    torch.manual_seed(9)
    m = nw.EncoderDecoder(latent_dim=4, encoder_hidden=8, encoder_layers=2, decoder_hidden=8, decoder_layers=2,
                          logvar_max=2.0)
    last = m.encoder[-1]
    with torch.no_grad():  # the encoder's output is its last layer's bias: raw log-variances known
        last.weight.zero_()
        last.bias.copy_(torch.tensor([0.1, -0.2, 0.3, 0.4, -3.0, 1.5, 7.0, 200.0]))
    v = torch.randn(5, 23)
    mu, logvar = m.encode(v)
    assert torch.equal(mu, last.bias[:4].detach().expand(5, 4))
    assert torch.equal(logvar[0], torch.tensor([-3.0, 1.5, 2.0, 2.0]))  # capped above, untouched below
    kl = nw.kl_divergence(mu, logvar)
    assert torch.isfinite(kl)  # exp(200) would overflow float32
    kl.backward()
    # straight through: d KL / d raw = 0.5 * (exp(capped) - 1) per sample, mean over the batch, also above the cap
    expected = 0.5 * (torch.exp(logvar[0].detach()) - 1.0)
    assert torch.allclose(last.bias.grad[4:], expected)
    assert expected[3] > 0  # the sample thrown far up is pulled back down
    # an uncapped twin: the same weights give the same mu and the raw log-variance
    u = nw.EncoderDecoder(latent_dim=4, encoder_hidden=8, encoder_layers=2, decoder_hidden=8, decoder_layers=2)
    u.load_state_dict(m.state_dict())
    mu_u, lv_u = u.encode(v)
    assert torch.equal(mu_u, mu) and torch.equal(lv_u[0], last.bias[4:].detach())
    assert "logvar_max" not in u.config  # an unbounded model's config is the paper's layout
    nw.save_model(m, tmp_path / "capped.pt")
    loaded = nw.load_model(tmp_path / "capped.pt")
    assert loaded.logvar_max == 2.0 and torch.equal(loaded.encode(v)[1], logvar.detach())


def test_reevaluator_converts_scalings():
    torch.manual_seed(8)
    emu = nw.Emulator(hidden=8, layers=3).double()
    m = nw.EncoderDecoder(latent_dim=2, encoder_hidden=4, encoder_layers=2, decoder_hidden=4, decoder_layers=2).double()
    rng = np.random.default_rng(1)
    v, y = rng.normal(3, 2, (50, 23)), rng.normal(-1, 4, (50, 16))
    emu.x_scaler.fit(v)
    emu.y_scaler.fit(y)
    m.x_scaler.fit(v[:30] * 1.1)
    m.y_scaler.fit(y[:30] + 0.5)
    vs = torch.randn(5, 23, dtype=torch.float64)
    expected = m.y_scaler.transform(emu.y_scaler.inverse(emu(emu.x_scaler.transform(m.x_scaler.inverse(vs)))))
    assert torch.allclose(nw.make_reevaluator(emu, m)(vs), expected, atol=1e-10)
    m.x_scaler.load_state_dict(emu.x_scaler.state_dict())
    m.y_scaler.load_state_dict(emu.y_scaler.state_dict())
    assert torch.equal(nw.make_reevaluator(emu, m)(vs), emu(vs))


def test_log_standardizer_round_trip_positivity_and_errors(tmp_path):
    """Log columns standardized as logarithms (unit std of log v), the others as they are; inverse
    undoes transform (numpy and torch); any decoded value is positive in a log column; a value
    <= 0 there is refused with its column named."""
    rng = np.random.default_rng(3)
    v = np.exp(rng.normal(0.0, 0.5, (400, 23))) * 10.0
    v[:, 1] = rng.normal(-4.0, 1.0, 400)  # a parameter that may be negative (P_th)
    cols = [j for j in range(23) if j != 1]
    s = nw.LogStandardizer(23, cols).double().fit(v)
    u = s.transform(v)
    assert np.allclose(u.mean(0), 0.0, atol=1e-12) and np.allclose(u.std(0), 1.0)
    assert np.allclose(s.mean.double().numpy()[cols], np.log(v[:, cols]).mean(0))
    assert np.allclose(s.mean.double().numpy()[1], v[:, 1].mean())
    assert np.allclose(s.inverse(u), v, rtol=1e-12)
    t = torch.as_tensor(v)
    assert torch.allclose(s.inverse(s.transform(t)), t, rtol=1e-12)
    far = s.inverse(rng.normal(0.0, 10.0, (1000, 23)))
    assert (far[:, cols] > 0).all() and (far[:, 1] < 0).any()
    bad = v[:3].copy()
    bad[2, 7] = -0.1
    with pytest.raises(ValueError, match="column 7 .* <= 0"):
        s.transform(bad)
    with pytest.raises(ValueError, match="column 7"):
        nw.LogStandardizer(23, cols).fit(bad)
    with pytest.raises(ValueError, match="log_columns"):
        nw.LogStandardizer(23, [23])
    # an encoder/decoder with log_params saves and loads it, and decodes positive parameters
    m = nw.EncoderDecoder(latent_dim=2, encoder_hidden=4, encoder_layers=2, decoder_hidden=4, decoder_layers=2,
                          log_params=cols).double()
    m.x_scaler.fit(v)
    m.y_scaler.fit(rng.normal(0.0, 1.0, (400, 16)))
    nw.save_model(m, tmp_path / "m.pt")
    back = nw.load_model(tmp_path / "m.pt")
    assert isinstance(back.x_scaler, nw.LogStandardizer) and back.config["log_params"] == cols
    y, w = rng.normal(0.0, 3.0, (50, 16)), rng.normal(0.0, 5.0, (50, 2))
    assert np.array_equal(back.invert(y, w), m.invert(y, w)) and (m.invert(y, w)[:, cols] > 0).all()
    assert "log_params" not in nw.EncoderDecoder().config  # the paper's (and the published) models


def test_reevaluator_through_log_parameters():
    """With log_params the re-evaluator maps through physical units: exp, then the emulator's own
    standardization (it equals predict on the physical parameters)."""
    torch.manual_seed(8)
    emu = nw.Emulator(hidden=8, layers=3).double()
    rng = np.random.default_rng(2)
    v, y = np.exp(rng.normal(1.0, 0.4, (60, 23))), rng.normal(-1, 4, (60, 16))
    emu.x_scaler.fit(v)
    emu.y_scaler.fit(y)
    m = nw.EncoderDecoder(latent_dim=2, encoder_hidden=4, encoder_layers=2, decoder_hidden=4, decoder_layers=2,
                          log_params=list(range(23))).double()
    m.x_scaler.fit(v)
    m.y_scaler.fit(y + 0.5)
    got = m.y_scaler.inverse(nw.make_reevaluator(emu, m)(m.x_scaler.transform(torch.as_tensor(v[:7]))))
    assert torch.allclose(got, torch.as_tensor(emu.predict(v[:7])), atol=1e-10)


def test_draw_noise_std():
    g = torch.Generator().manual_seed(9)
    eta = nw.draw_noise(100_000, 0.5, g)
    assert eta.shape == (100_000, N_OUTPUTS)
    assert np.allclose(eta.std(0).numpy(), 0.5 * noise_std(), rtol=0.02)
    assert np.all(np.abs(eta.mean(0).numpy()) < 0.02 * noise_std())
    assert not torch.equal(eta[:10], nw.draw_noise(10, 0.5, g))  # fresh draws
    assert torch.equal(nw.draw_noise(7, 0.0, g), torch.zeros(7, N_OUTPUTS))


# ----------------------------------------------------------------------------- save / load
def _fitted(model):
    rng = np.random.default_rng(2)
    for name, s in model.named_children():
        if isinstance(s, nw.Standardizer):
            s.fit(rng.normal(rng.uniform(-5, 5), rng.uniform(0.5, 3), size=(40, s.mean.numel())))
    return model


@pytest.mark.parametrize("make", [
    lambda: nw.Emulator(hidden=16, layers=3),
    lambda: nw.Emulator(hidden=16, layers=3, linear_skip=True, log_inputs=[0, 4, 22]),
    lambda: nw.RealNVP(hidden=8, blocks=3, batchnorm=True),
    lambda: nw.EncoderDecoder(latent_dim=4, encoder_hidden=8, encoder_layers=3, decoder_hidden=8, decoder_layers=3),
])
def test_save_load_roundtrip(tmp_path, make):
    torch.manual_seed(10)
    model = _fitted(make())
    if isinstance(model, nw.RealNVP):
        model.train()
        model(torch.randn(64, 16))  # running stats
    model.eval()
    path = tmp_path / "m.pt"
    nw.save_model(model, path, info={"seed": 3, "note": "x"})
    loaded, info = nw.load_model(path, with_info=True)
    assert type(loaded) is type(model) and not loaded.training
    assert info == {"seed": 3, "note": "x"}
    sd, sd2 = model.state_dict(), loaded.state_dict()
    assert sd.keys() == sd2.keys() and all(torch.equal(sd[k], sd2[k]) for k in sd)
    with torch.no_grad():
        if isinstance(model, nw.Emulator):
            v = np.random.default_rng(3).normal(size=(20, N_PARAMETERS))
            assert np.array_equal(model.predict(v), loaded.predict(v))
        elif isinstance(model, nw.RealNVP):
            y = torch.randn(20, 16)
            assert torch.equal(model.log_prob(y), loaded.log_prob(y))
            assert torch.equal(model.sample(5, torch.Generator().manual_seed(1)),
                               loaded.sample(5, torch.Generator().manual_seed(1)))
        else:
            y, w = np.random.default_rng(4).normal(size=(20, 16)), np.zeros((20, 4))
            assert np.array_equal(model.invert(y, w), loaded.invert(y, w))
            v = torch.randn(20, 23)
            assert torch.equal(model(v, torch.zeros(20, 16), None)[0], loaded(v, torch.zeros(20, 16), None)[0])


def test_load_rejects_foreign_file(tmp_path):
    torch.save({"state_dict": {}}, tmp_path / "x.pt")
    with pytest.raises(ValueError, match="not a"):
        nw.load_model(tmp_path / "x.pt")
