"""Algorithm 1 (missing data) and latent decoding, on small untrained networks."""
import numpy as np
import pytest
import torch

from cvsim6.inference import inversion
from cvsim6 import nets as networks
from cvsim6 import registry


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
    a = inversion.decode_latent(ed, y, 5, seed=2, corrector_steps=0)
    b = inversion.decode_latent(ed, y, 5, seed=2, corrector_steps=0)
    assert a.shape == (3, 5, 23) and np.array_equal(a, b)
    assert not np.allclose(a[:, 0], a[:, 1])  # different latent draws, different parameters


def test_decode_latent_corrector_steps():
    """0 steps = the decoder at w ~ N(0, I); k steps = k rounds of w <- mu(NN_v(v)) by hand."""
    torch.manual_seed(0)
    ed = networks.EncoderDecoder()
    y = np.random.default_rng(1).normal(size=(2, 16)) * 10 + 50
    w = torch.randn(2 * 4, ed.latent_dim, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    y_rep = np.repeat(y, 4, axis=0)
    plain = inversion.decode_latent(ed, y, 4, seed=3, corrector_steps=0)
    np.testing.assert_array_equal(plain.reshape(-1, 23), ed.invert(y_rep, w.float().numpy(), corrector_steps=0))
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


def test_corrector_steps_have_one_default():
    """The library, the workflow's functions and the CLI decode with the same default."""
    import inspect

    from cvsim6 import cli
    from cvsim6.studies import ehr as ehr_study

    assert networks.DEFAULT_CORRECTOR_STEPS == 2  # the paper's code
    for f in (networks.EncoderDecoder.invert, inversion.decode_latent, ehr_study.invert_observations,
              ehr_study.invert_ehr_patients):
        assert inspect.signature(f).parameters["corrector_steps"].default == networks.DEFAULT_CORRECTOR_STEPS, f
    args = cli.build_parser().parse_args(["invert", "obs.csv", "-o", "out.csv"])
    assert args.corrector_steps == networks.DEFAULT_CORRECTOR_STEPS
    torch.manual_seed(0)
    ed = networks.EncoderDecoder()
    y = np.random.default_rng(1).normal(size=(2, 16)) * 10 + 50
    by_default = inversion.decode_latent(ed, y, 3, seed=1)
    np.testing.assert_array_equal(by_default, inversion.decode_latent(ed, y, 3, seed=1, corrector_steps=2))
    assert not np.allclose(by_default, inversion.decode_latent(ed, y, 3, seed=1, corrector_steps=0))


def test_reference_scores_are_algorithm_1_per_row(flow):
    """Completing every reference row with one shared sample set gives, row by row, what
    Algorithm 1 gives that row with the same seed; nothing missing = the row's own density."""
    rng = np.random.default_rng(4)
    y = rng.normal(size=(7, 16)) * registry.noise_std() + 50.0
    missing = np.isnan(observation())
    got = inversion.reference_scores(flow, y, missing, 5000, seed=9, max_rows_per_pass=3 * 5000)
    for i in range(len(y)):
        one = inversion.complete_missing(flow, np.where(missing, np.nan, y[i]), 5000, seed=9)[1][0]
        assert got[i] == pytest.approx(one, rel=1e-6, abs=1e-6)
    full = inversion.reference_scores(flow, y, np.zeros(16, bool), 5000)
    np.testing.assert_allclose(full, flow.log_prob_physical(y))


def test_ood_percentile_resolution():
    """With n reference scores the percentile moves in steps of 100/n; non-finite ones do not count."""
    ref = np.r_[np.arange(1000.0), -np.inf, np.nan]
    assert inversion.ood_percentile(0.5, ref) == pytest.approx(0.1)
    assert inversion.ood_percentile(-5.0, ref) == 0.0
    assert np.isnan(inversion.ood_percentile(1.0, [np.nan]))
