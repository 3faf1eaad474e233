"""Algorithm 1 (missing data) and latent decoding, on small untrained networks."""
import numpy as np
import pytest
import torch
from scipy import stats

from conftest import gaussian_log_density, identity_couplings
from cvsim6.inference import inversion
from cvsim6 import nets as networks
from cvsim6 import paper_values
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
    samples = np.vstack([flow.sample_physical(4096, inversion.seeded_torch_generator(inversion._block_seed(1, b)))
                         for b in range(2)])
    samples[:, obs] = y[obs]
    all_lp = flow.log_prob_physical(samples)
    np.testing.assert_allclose(np.sort(all_lp)[::-1][:3], lp, rtol=1e-12)


def test_shared_samples_complete_each_row_as_if_alone(flow):
    """Rows with different missing sets, ranked against one shared stream of 3 chunks, get what
    each row gets alone, and the top-k of a brute-force ranking of that stream."""
    a = observation()
    b = np.full(16, 48.0)
    b[[0, 1, 3]] = np.nan
    full = np.full(16, 51.0)
    rows = np.vstack([a, full, b])
    shared = inversion.complete_missing_shared(flow, rows, 10000, top_k=3, seed=5, chunk_size=4096)
    samples = np.vstack([flow.sample_physical(min(4096, 10000 - 4096 * k),
                                              inversion.seeded_torch_generator(inversion._block_seed(5, k)))
                         for k in range(3)])
    for y, (best, lp) in zip(rows, shared):
        alone = inversion.complete_missing(flow, y, 10000, top_k=3, seed=5, chunk_size=4096)
        np.testing.assert_array_equal(best, alone[0])
        np.testing.assert_array_equal(lp, alone[1])
        seen = np.isfinite(y)
        assert (best[:, seen] == y[seen]).all()
        if seen.all():
            assert best.shape == (1, 16)
            continue
        brute = samples.copy()
        brute[:, seen] = y[seen]
        np.testing.assert_allclose(np.sort(flow.log_prob_physical(brute))[::-1][:3], lp, rtol=1e-6)


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
    # the CLI's: None = the library's, resolved when the command runs (tests/test_cli.py checks that
    # `cvsim6 invert` without --corrector-steps equals the library at its default)
    args = cli.build_parser().parse_args(["invert", "obs.csv", "-o", "out.csv"])
    assert args.corrector_steps in (None, networks.DEFAULT_CORRECTOR_STEPS)
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


# ----------------------------------------------------------------------------- Algorithm 1, closed form
class IndependentGaussian:
    """A density estimator with the interface Algorithm 1 uses (``eval``, ``sample_physical``,
    ``log_prob_physical``) whose density is N(mean, diag(std^2)) in physical units, float64."""

    def __init__(self, mean: np.ndarray, std: np.ndarray):
        self.mean, self.std = np.asarray(mean, float), np.asarray(std, float)

    def eval(self):
        return self

    def sample_physical(self, n: int, generator: torch.Generator | None = None) -> np.ndarray:
        z = torch.randn(n, len(self.mean), generator=generator, dtype=torch.float64).numpy()
        return self.mean + self.std * z

    def log_prob_physical(self, y: np.ndarray) -> np.ndarray:
        return gaussian_log_density(y, self.mean, self.std)


GAUSS_MEAN = np.array(paper_values.Y_STAR)  # registry units
GAUSS_STD = 4 * registry.noise_std()


def gaussian_density(kind: str) -> tuple:
    """``(flow, mean, std, tolerance in nats)``: the Gaussian itself, or a RealNVP (float32) whose
    couplings are the identity and whose output scaler holds that mean and std."""
    if kind == "gaussian":
        return IndependentGaussian(GAUSS_MEAN, GAUSS_STD), GAUSS_MEAN, GAUSS_STD, 1e-9
    torch.manual_seed(0)
    flow = identity_couplings(networks.RealNVP(hidden=8, blocks=4, layers_per_block=3))
    with torch.no_grad():
        flow.y_scaler.mean.copy_(torch.as_tensor(GAUSS_MEAN))
        flow.y_scaler.std.copy_(torch.as_tensor(GAUSS_STD))
    return flow.eval(), flow.y_scaler.mean.double().numpy(), flow.y_scaler.std.double().numpy(), 1e-4


MISSING_SETS = {"paper's seven": [2, 4, 6, 8, 10, 14, 15], "two": [4, 14]}


@pytest.mark.parametrize("kind", ["gaussian", "real_nvp"])
@pytest.mark.parametrize("missing_set", list(MISSING_SETS))
def test_algorithm_1_completes_a_gaussian_with_its_mean(kind, missing_set):
    """Under an independent Gaussian N(m, diag(s^2)) the most likely completion sets each missing
    output j to m_j; its log-density is log N(observed part) - sum over the k missing j of
    log(s_j sqrt(2 pi)), and any other completion lies d^2 / 2 nats below it, d^2 its squared
    standardized distance over the missing outputs. Algorithm 1 with M samples keeps the
    smallest of M chi^2_k draws of d^2: below the chi^2_k quantile at 30/M except with
    probability (1 - 30/M)^M < e^-30, and its 5th smallest below the quantile at 60/M (at least 5
    of M draws fall there except with probability < 1e-19)."""
    flow, mean, std, tol = gaussian_density(kind)
    missing = np.zeros(16, bool)
    missing[MISSING_SETS[missing_set]] = True
    k, n_samples = int(missing.sum()), 20000
    y = np.where(missing, np.nan, mean + np.linspace(-1.5, 1.5, 16) * std)  # observed up to 1.5 sd off
    best, lp = inversion.complete_missing(flow, y, n_samples, top_k=5, seed=4)
    assert (best[:, ~missing] == y[~missing]).all()
    mode_lp = gaussian_log_density(np.where(missing, mean, y), mean, std)[0]
    np.testing.assert_allclose(lp, gaussian_log_density(best, mean, std), rtol=0, atol=tol)
    d2 = ((((best - mean) / std)[:, missing]) ** 2).sum(axis=1)
    np.testing.assert_allclose(mode_lp - lp, d2 / 2, rtol=0, atol=tol)
    assert (np.diff(lp) <= 0).all() and (lp <= mode_lp + tol).all()
    q_best, q_fifth = stats.chi2.ppf(30 / n_samples, k), stats.chi2.ppf(60 / n_samples, k)
    assert d2[0] <= q_best and d2[-1] <= q_fifth
    assert (np.abs(best[0, missing] - mean[missing]) <= np.sqrt(q_best) * std[missing]).all()
    if k == 2:  # two missing outputs: the best completion within 0.06 standard deviations of the mean
        assert np.sqrt(q_best) < 0.06
