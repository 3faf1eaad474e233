"""Algorithm 1 (missing data) and latent decoding, on small untrained networks."""
import numpy as np
import pytest
import torch

from cvsim6 import inversion, networks, registry


@pytest.fixture(scope="module")
def flow():
    torch.manual_seed(0)
    f = networks.RealNVP(hidden=8, blocks=4, layers_per_block=3, batchnorm=False)
    y = np.random.default_rng(0).normal(size=(500, 16)) * registry.noise_std() + 50.0
    f.y_scaler.fit(y)
    return f.eval()


def observation():
    y = np.full(16, 50.0)
    y[[2, 4, 6, 8, 10, 14, 15]] = np.nan  # the paper's missing set, in spirit
    return y


def test_chunking_gives_the_same_ranking_as_one_pass(flow):
    y = observation()
    one = inversion.complete_missing(flow, y, 20000, top_k=4, seed=3, chunk_size=10**6)
    small = inversion.complete_missing(flow, y, 20000, top_k=4, seed=3, chunk_size=4096)
    np.testing.assert_array_equal(one[0], small[0])
    np.testing.assert_array_equal(one[1], small[1])
    assert (np.diff(one[1]) <= 0).all()  # best first


def test_completions_keep_observed_entries_and_are_the_most_likely(flow):
    y = observation()
    best, lp = inversion.complete_missing(flow, y, 8192, top_k=3, seed=1)
    obs = np.isfinite(y)
    assert (best[:, obs] == y[obs]).all()
    assert np.isfinite(best).all()
    # brute force over the same sample stream: no sample beats the kept ones
    samples = np.vstack([flow.sample_physical(4096, inversion._generator(inversion._block_seed(1, b)))
                         for b in range(2)])
    samples[:, obs] = y[obs]
    all_lp = flow.log_prob_physical(samples)
    np.testing.assert_allclose(np.sort(all_lp)[::-1][:3], lp, rtol=1e-12)


def test_complete_observation_is_returned_unchanged(flow):
    y = np.full(16, 50.0)
    best, lp = inversion.complete_missing(flow, y, 100, top_k=1)
    assert (best[0] == y).all()
    np.testing.assert_allclose(lp, flow.log_prob_physical(y[None]))


def test_decode_latent_shapes_and_seed():
    torch.manual_seed(0)
    ed = networks.EncoderDecoder()
    y = np.random.default_rng(0).normal(size=(3, 16))
    a = inversion.decode_latent(ed, y, 5, seed=2)
    b = inversion.decode_latent(ed, y, 5, seed=2)
    assert a.shape == (3, 5, 23) and np.array_equal(a, b)
    assert not np.allclose(a[:, 0], a[:, 1])  # different latent draws, different parameters


def test_decode_latent_corrector_steps():
    """0 steps = the decoder at w ~ N(0, I); k steps = k rounds of w <- mu(NN_v(v)) by hand."""
    torch.manual_seed(0)
    ed = networks.EncoderDecoder()
    y = np.random.default_rng(1).normal(size=(2, 16)) * 10 + 50
    w = torch.randn(2 * 4, ed.latent_dim, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    y_rep = np.repeat(y, 4, axis=0)
    plain = inversion.decode_latent(ed, y, 4, seed=3)
    np.testing.assert_array_equal(plain.reshape(-1, 23), ed.invert(y_rep, w.float().numpy()))
    v = plain.reshape(-1, 23)
    with torch.no_grad():
        for _ in range(2):
            mu, _ = ed.encode(ed.x_scaler.transform(torch.as_tensor(v, dtype=torch.float32)))
            v = ed.invert(y_rep, mu.numpy())
    corrected = inversion.decode_latent(ed, y, 4, seed=3, corrector_steps=2)
    np.testing.assert_allclose(corrected.reshape(-1, 23), v, rtol=1e-5, atol=1e-5)
    assert not np.allclose(corrected, plain)
    with pytest.raises(ValueError, match="corrector_steps"):
        inversion.decode_latent(ed, y, 4, corrector_steps=-1)


def test_ood_percentile():
    ref = np.arange(100.0)
    assert inversion.ood_percentile(-1.0, ref) == 0.0
    assert inversion.ood_percentile(49.5, ref) == 50.0
    assert inversion.ood_percentile(1e9, ref) == 100.0
