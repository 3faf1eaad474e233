"""Calibration diagnostics on problems whose answer is known: a Gaussian toy with an exact
posterior (a calibrated sampler passes, an over-confident one fails, an under-confident one
is flagged the other way), and constructed samples with known ranks, spread and bias."""
import numpy as np
import pytest

from cvsim6.inference import calibration


def gaussian_toy(n_cases=400, n_samples=100, d=3, noise=0.5, std_scale=1.0, seed=0):
    """theta ~ N(0, 1), x = theta + N(0, noise^2): the posterior is N(x / (1 + noise^2),
    noise^2 / (1 + noise^2)); samples from it with the standard deviation times ``std_scale``."""
    rng = np.random.default_rng(seed)
    theta = rng.normal(size=(n_cases, d))
    x = theta + noise * rng.normal(size=theta.shape)
    mean = x / (1 + noise**2)
    std = np.sqrt(noise**2 / (1 + noise**2)) * std_scale
    samples = mean[:, None, :] + std * rng.normal(size=(n_cases, n_samples, d))
    return theta, samples


BOX = (np.full(3, -4.0), np.full(3, 4.0))


def test_exact_posterior_is_calibrated():
    theta, samples = gaussian_toy()
    diag = calibration.diagnostics(theta, samples, *BOX)
    assert (diag["sbc_pvalue"] > 0.01).all(), diag["sbc_pvalue"]
    assert (diag["coverage_error"] < 0.05).all(), diag["coverage_error"]
    tarp = calibration.tarp(theta, samples, *BOX, seed=1)
    assert abs(tarp["atc"]) < 0.03 and tarp["ks_pvalue"] > 0.05


def test_over_confident_sampler_fails():
    theta, samples = gaussian_toy(std_scale=0.5)
    diag = calibration.diagnostics(theta, samples, *BOX)
    assert (diag["sbc_pvalue"] < 1e-6).all(), diag["sbc_pvalue"]
    assert (diag["coverage_error"] > 0.15).all(), diag["coverage_error"]
    # empirical coverage below nominal at every level: intervals too narrow
    assert (diag["coverage"] < calibration.COVERAGE_LEVELS[:, None]).all()
    assert calibration.tarp(theta, samples, *BOX, seed=1)["atc"] < -0.03


def test_under_confident_sampler_is_flagged_the_other_way():
    theta, samples = gaussian_toy(std_scale=2.0)
    diag = calibration.diagnostics(theta, samples, *BOX)
    assert (diag["sbc_pvalue"] < 1e-6).all()
    assert (diag["coverage"][3:] > calibration.COVERAGE_LEVELS[3:, None]).all()
    assert calibration.tarp(theta, samples, *BOX, seed=1)["atc"] > 0.03


def test_ranks_coverage_contraction_and_nrmse_known_values():
    # two cases, one parameter, samples 0..9: the true values 4.5 and -1 have ranks 5 and 0
    samples = np.tile(np.arange(10.0)[None, :, None], (2, 1, 1))
    theta = np.array([[4.5], [-1.0]])
    np.testing.assert_array_equal(calibration.sbc_ranks(theta, samples), [[5], [0]])
    cov = calibration.coverage(theta, samples, levels=np.array([0.1, 0.9]))
    np.testing.assert_array_equal(cov[:, 0], [0.5, 0.5])  # 4.5 is the median, -1 is outside both
    # samples +-a around theta + c: variance a^2, posterior-mean error c
    a, c, width = 0.3, 0.2, 2.0
    theta = np.zeros((5, 2))
    samples = theta[:, None, :] + c + np.array([-a, a])[None, :, None]
    lo, hi = np.full(2, -1.0), np.full(2, 1.0)
    np.testing.assert_allclose(calibration.contraction(samples, lo, hi), 1 - a**2 / (width**2 / 12))
    np.testing.assert_allclose(calibration.nrmse(theta, samples, lo, hi), c / (width / np.sqrt(12)))


def test_shapes_are_checked():
    with pytest.raises(ValueError, match=r"theta \(n, d\) and samples \(n, N, d\)"):
        calibration.sbc_ranks(np.zeros((4, 2)), np.zeros((4, 10, 3)))
