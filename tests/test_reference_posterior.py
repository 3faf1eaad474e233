"""MCMC reference posteriors (cvsim6.inference.reference_posterior): the sampler on a Gaussian toy
with an exact posterior, the model's exact cases, and the comparison measures."""
from __future__ import annotations

import numpy as np
import pytest

from cvsim6.data import priors
from cvsim6.inference import reference_posterior as rp
from cvsim6.model import solver
from cvsim6.registry import OUTPUT_INDEX, PARAMETER_INDEX, noise_std

# Linear-Gaussian toy: y = M theta, 4 outputs of which 3 observed, 3 parameters.
M = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, -0.3], [0.2, 0.0, 1.0], [5.0, 5.0, 5.0]])
SIGMA = np.array([0.3, 0.2, 0.25, 1.0])
Y_OBS = np.array([1.0, -0.5, 0.7, np.nan])  # the 4th output is not observed


def exact_posterior() -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the toy's posterior under a flat prior (the box is far wider)."""
    A, s, y = M[:3], SIGMA[:3], Y_OBS[:3]
    precision = A.T @ np.diag(s**-2) @ A
    cov = np.linalg.inv(precision)
    return cov @ A.T @ (y / s**2), cov


def toy_posterior() -> rp.BoxPosterior:
    return rp.BoxPosterior(lambda theta: theta @ M.T, Y_OBS, SIGMA, np.full(3, -6.0), np.full(3, 6.0))


def toy_run(seed: int, steps: int) -> tuple[rp.BoxPosterior, dict]:
    post = toy_posterior()
    start = rp.start_walkers(post, 16, np.random.default_rng(seed), prior_draws=500, iterations=3)
    return post, rp.run_ensemble(post, start, seed, min_steps=steps, max_steps=steps, check_every=steps)


def test_sampler_recovers_an_exact_gaussian_posterior():
    mean, cov = exact_posterior()
    sd = np.sqrt(np.diag(cov))
    assert (6 - np.abs(mean) > 8 * sd).all()  # the box does not truncate it
    post, res = toy_run(seed=4, steps=4000)
    assert res["converged"] and (res["rhat"] <= 1.05).all() and (res["ess_bulk"] >= 400).all()
    theta = post.to_physical(res["chain"].reshape(-1, 3))
    ess = np.minimum(res["ess_bulk"], res["ess_tail"])
    # means within 4 Monte Carlo standard errors sd / sqrt(ESS)
    assert (np.abs(theta.mean(axis=0) - mean) < 4 * sd / np.sqrt(ess)).all()
    # variances within 4 standard errors var sqrt(2 / ESS), correlations within 0.1
    got = np.cov(theta.T)
    assert (np.abs(np.diag(got) - sd**2) < 4 * sd**2 * np.sqrt(2 / ess)).all()
    corr = cov / np.outer(sd, sd)
    got_corr = got / np.sqrt(np.outer(np.diag(got), np.diag(got)))
    assert np.abs(got_corr - corr).max() < 0.1
    assert abs(corr[0, 1]) > 0.3  # a correlated target, not a trivially factorized one


def test_sampler_is_bit_reproducible():
    _, a = toy_run(seed=9, steps=200)
    _, b = toy_run(seed=9, steps=200)
    _, c = toy_run(seed=10, steps=200)
    np.testing.assert_array_equal(a["chain"], b["chain"])
    assert not np.array_equal(a["chain"], c["chain"])
    assert a["chain"].shape == (16, 100, 3) and a["steps"] == 200


def test_log_prob_outside_the_box_or_without_output():
    post = toy_posterior()
    u = np.array([[0.5, 0.5, 0.5], [1.2, 0.5, 0.5], [0.0, 0.5, 0.5]])
    lp = post.log_prob(u)
    assert np.isfinite(lp[0]) and lp[1] == -np.inf and lp[2] == -np.inf
    assert post.evaluations == 1  # points outside the open box are not simulated
    # at theta = 0 (u = 1/2): chi^2 over the observed outputs only
    assert lp[0] == pytest.approx(-0.5 * ((Y_OBS[:3] / SIGMA[:3]) ** 2).sum())
    nan_post = rp.BoxPosterior(lambda t: np.full((len(t), 4), np.nan), Y_OBS, SIGMA, -np.ones(3), np.ones(3))
    assert nan_post.log_prob(np.full((2, 3), 0.5)).tolist() == [-np.inf, -np.inf]


def test_bad_targets_are_named():
    with pytest.raises(ValueError, match="no observed output"):
        rp.BoxPosterior(lambda t: t, np.full(3, np.nan), np.ones(3), np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match="standard deviations must be > 0"):
        rp.BoxPosterior(lambda t: t, np.ones(3), np.array([1.0, 0.0, 1.0]), np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match=r"prior box of parameter 1 is empty: \[0.0, 0.0\]"):
        rp.BoxPosterior(lambda t: t, np.ones(3), np.ones(3), np.zeros(3), np.array([1.0, 0.0, 2.0]))
    with pytest.raises(ValueError, match="max_steps"):
        rp.run_ensemble(toy_posterior(), np.full((16, 3), 0.5), 0, min_steps=10, max_steps=5, check_every=1)


def test_walkers_never_start_on_a_shared_face_value():
    # a posterior whose mode lies beyond the box: the steps push the starts onto the face of the
    # first parameter, but they must differ there (an ensemble cannot spread a shared coordinate)
    post = rp.BoxPosterior(lambda t: t, np.array([10.0, 0.0, 0.0]), np.full(3, 0.1), -np.ones(3), np.ones(3))
    u = rp.start_walkers(post, 16, np.random.default_rng(0), prior_draws=200, iterations=8)
    assert (u[:, 0] > 0.9).all() and len(np.unique(u[:, 0])) == 16
    assert ((u > 0) & (u < 1)).all()
    # and a well-determined coordinate starts with about the posterior's width (sd 0.1 of 2: 0.05)
    post = rp.BoxPosterior(lambda t: t, np.zeros(3), np.array([0.1, 10.0, 10.0]), -np.ones(3), np.ones(3))
    u = rp.start_walkers(post, 200, np.random.default_rng(0), prior_draws=400, iterations=4)
    assert 0.025 < u[:, 0].std() < 0.1


def test_exact_cases_of_the_model():
    """Only Hr and SVR observed: the Hr output is the Hr parameter and SVR = R_a (unit
    conversion), so the posteriors of Hr and R_a are Gaussians of known mean and width (inside
    the prior box), and every other parameter keeps its uniform prior."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["ehr"])
    theta = priors.sample_uniform(lo, hi, 1, np.random.default_rng(3))
    theta[0, PARAMETER_INDEX["Hr"]], theta[0, PARAMETER_INDEX["R_a"]] = 90.0, 0.8
    y, status = solver.simulate_batch(theta, steps_per_cycle=100)
    assert status[0] == 0
    svr_per_ra = y[0, OUTPUT_INDEX["SVR"]] / 0.8
    y_obs = np.full(16, np.nan)
    y_obs[OUTPUT_INDEX["Hr"]], y_obs[OUTPUT_INDEX["SVR"]] = 91.0, 0.8 * svr_per_ra + 10.0
    sigma = 0.5 * noise_std()
    post = rp.BoxPosterior(rp.simulator_function({"steps_per_cycle": 100, "n_cycles": 12, "window_cycles": 3}),
                           y_obs, sigma, lo, hi)
    start = rp.start_walkers(post, 48, np.random.default_rng(1), prior_draws=200, iterations=2)
    res = rp.run_ensemble(post, start, 1, min_steps=400, max_steps=400, check_every=400)
    draws = post.to_physical(res["chain"].reshape(-1, 23))
    ess = np.minimum(res["ess_bulk"], res["ess_tail"])
    for name, mean, sd in (("Hr", 91.0, sigma[OUTPUT_INDEX["Hr"]]),
                           ("R_a", 0.8 + 10.0 / svr_per_ra, sigma[OUTPUT_INDEX["SVR"]] / svr_per_ra)):
        j = PARAMETER_INDEX[name]
        assert abs(draws[:, j].mean() - mean) < 4 * sd / np.sqrt(ess[j]), name
        assert draws[:, j].std() == pytest.approx(sd, rel=0.25), name
    # a parameter no observed output depends on keeps (about) its prior's mean and spread
    j = PARAMETER_INDEX["C_pa"]
    u = (draws[:, j] - lo[j]) / (hi[j] - lo[j])
    assert abs(u.mean() - 0.5) < 0.1 and u.std() == pytest.approx(np.sqrt(1 / 12), rel=0.2)


def test_c2st_and_moments():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(400, 3)), rng.normal(size=(300, 3))
    assert abs(rp.c2st_accuracy(a, b, seed=1) - 0.5) < 0.1
    assert rp.c2st_accuracy(a, b + 10.0, seed=1) > 0.98
    assert np.isnan(rp.c2st_accuracy(a, b[:5], seed=1))  # too few rows for 5 folds
    lo, hi = np.zeros(3), np.full(3, 4.0)
    shifted = np.column_stack([b[:, 0] * 2 + 2.0, b[:, 1], b[:, 2]])
    diff, ratio = rp.compare_moments(b, shifted, lo, hi)
    np.testing.assert_allclose(diff, [(2.0 + b[:, 0].mean()) / 4, 0, 0], atol=1e-12)
    np.testing.assert_allclose(ratio, [2, 1, 1], rtol=1e-12)
    assert rp.thin(np.zeros((8, 100, 3)), 50).shape == (50, 3)
    assert rp.thin(np.zeros((8, 10, 3)), 500).shape == (80, 3)
