"""The NPE baseline (sbi): the bounded-prior reparameterization, the save/load round trip and
what a trained estimator learns on a problem with a known answer."""
import numpy as np
import pytest

pytestmark = pytest.mark.slow  # trains small estimators (about half a minute)

from cvsim6.inference import npe

LO, HI = np.full(23, 1.0), np.full(23, 3.0)


def toy_pairs(n, seed, noise=0.02):
    """theta uniform in [1, 3]^23; y observes the first 16 parameters with small noise."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(LO, HI, size=(n, 23))
    return theta, theta[:, :16] + noise * rng.normal(size=(n, 16))


def test_unbounded_coordinates_round_trip_and_reject_the_box_edge():
    theta, _ = toy_pairs(50, 0)
    u = npe.to_unbounded(theta, LO, HI)
    np.testing.assert_allclose(npe.from_unbounded(u, LO, HI), theta, rtol=1e-12)
    bad = theta.copy()
    bad[3, 7] = 3.0
    with pytest.raises(ValueError, match=r"row 3, parameter 7: 3 is not inside the prior box \(1, 3\)"):
        npe.to_unbounded(bad, LO, HI)


def test_unknown_setting_is_named():
    with pytest.raises(ValueError, match="unknown NPE setting"):
        npe.check_hyper({"hidden": 10})


@pytest.fixture(scope="module")
def trained():
    theta, y = toy_pairs(3000, 1)
    return npe.fit_npe(theta, y, LO, HI, {"max_epochs": 40, "hidden_features": 32, "num_transforms": 2,
                                          "batch_size": 256, "lr": 2e-3}, seed=5)


def test_save_load_gives_the_same_samples_with_the_same_seed(trained, tmp_path):
    post, losses = trained
    npe.save_npe(post, tmp_path / "npe.pt")
    loaded = npe.load_npe(tmp_path / "npe.pt")
    _, y = toy_pairs(4, 2)
    a = post.sample(y, 50, seed=3)
    np.testing.assert_array_equal(a, loaded.sample(y, 50, seed=3))
    assert not np.array_equal(a, loaded.sample(y, 50, seed=4))
    assert loaded.hyper == post.hyper and loaded.info["epochs_done"] == len(losses)
    # every sample inside the prior box, whatever the estimator
    assert (a >= LO).all() and (a <= HI).all()


def test_training_is_seeded_and_writes_nothing_beside(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    theta, y = toy_pairs(500, 1)
    hyper = {"max_epochs": 2, "hidden_features": 16, "num_transforms": 2}
    one, _ = npe.fit_npe(theta, y, LO, HI, hyper, seed=5)
    two, _ = npe.fit_npe(theta, y, LO, HI, hyper, seed=5)
    other, _ = npe.fit_npe(theta, y, LO, HI, hyper, seed=6)
    _, y_obs = toy_pairs(3, 2)
    a = one.sample(y_obs, 20, seed=0)
    np.testing.assert_array_equal(a, two.sample(y_obs, 20, seed=0))
    assert not np.array_equal(a, other.sample(y_obs, 20, seed=0))
    assert list(tmp_path.iterdir()) == []  # no TensorBoard folder (sbi-logs/) in the working directory


def test_posterior_learns_the_observed_parameters(trained):
    post, losses = trained
    assert losses["test_loss"].iloc[-1] < losses["test_loss"].iloc[0]
    theta, y = toy_pairs(40, 3)
    s = post.sample(y, 200, seed=0)
    err_seen = np.abs(s.mean(axis=1)[:, :16] - theta[:, :16]).mean()
    # the 7 unobserved parameters stay at their prior: mean 2, standard deviation 2/sqrt(12) = 0.577
    spread_unseen = s[:, :, 16:].std(axis=1).mean()
    assert err_seen < 0.15, err_seen  # 0.5 for the prior mean
    assert 0.45 < spread_unseen < 0.7, spread_unseen
