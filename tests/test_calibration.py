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


# ----------------------------------------------------------------------------- workflow step and figures
def _calibration_run(path, delta, theta, lo, hi, rng, n_samples=12):
    """A samples file: inVAErt's samples symmetric about the truth (mean exactly theta), NPE's
    shifted by 5% of the prior width."""
    half = rng.normal(size=(len(theta), n_samples // 2, theta.shape[1])) * 0.1 * (hi - lo)
    inv = theta[:, None, :] + np.concatenate([half, -half], axis=1)
    npe = theta[:, None, :] + 0.05 * (hi - lo) + rng.normal(size=inv.shape) * 0.1 * (hi - lo)
    np.savez_compressed(path, theta=theta, y_obs=np.zeros((len(theta), 16)), inVAErt=inv, NPE=npe,
                        noise_level=float(delta), seconds_inVAErt=2.0, seconds_NPE=1.0)


def test_calibration_summary_writes_the_figure_data_and_the_figures_draw_it(tmp_path, monkeypatch):
    """The step's figure data agree with its table (coverage error from the coverage curves,
    a mean exactly at the truth), and the figures draw those arrays; the Jacobian check and the
    NPE files are stubbed (3 parameters non-identifiable)."""
    import subprocess
    import sys
    import types

    import pandas as pd

    from cvsim6.data.priors import prior_bounds
    from cvsim6.registry import PARAMETER_NAMES
    from cvsim6.reporting import calibration_figures
    from cvsim6.studies import calibration as study

    prior = {"default": [0.7, 1.3]}
    lo, hi = prior_bounds(prior)
    rng = np.random.default_rng(0)
    theta = lo + (hi - lo) * rng.random((20, 23))
    for d in (0.5, 1.0):
        _calibration_run(tmp_path / f"samples_delta{d:g}.npz", d, theta, lo, hi, rng)
    share = np.r_[np.zeros(20), 0.5, 0.6, 0.7]
    monkeypatch.setattr(study, "nonidentifiable_parameters", lambda *a, **k: (share, np.full(4, 20)))
    monkeypatch.setattr(study, "load_npe", lambda p: types.SimpleNamespace(info={"noise_level": 1.0,
                                                                                 "train_seconds": 7.0}))
    out = {k: str(tmp_path / v) for k, v in (("csv", "s.csv"), ("md", "s.md"), ("figure_data", "f.npz"))}
    study.calibration_summary([str(tmp_path / "samples_delta0.5.npz"), str(tmp_path / "samples_delta1.npz")],
                              ["npe_delta1.pt"], **out, prior=prior, simulator={}, figure_noise_level=1.0,
                              identifiability_points=4, rel_step=1e-4, rank_rtol=1e-6, nonidentifiable_share=0.3,
                              seed=0)
    table = pd.read_csv(out["csv"])
    data = calibration_figures.read_figure_data(out["figure_data"])
    assert list(data["methods"]) == ["inVAErt", "NPE"] and list(data["parameters"]) == list(PARAMETER_NAMES)
    assert data["non_identifiable"].tolist() == [False] * 20 + [True] * 3
    assert data["noise_levels"].tolist() == [0.5, 1.0] and float(data["figure_noise_level"]) == 1.0
    assert data["coverage"].shape == (2, 2, 19, 23) and int(data["n_samples"]) == 12
    error = np.abs(data["coverage"] - data["coverage_levels"][None, None, :, None]).mean(axis=2)
    for i, m in enumerate(("inVAErt", "NPE")):
        for k, d in enumerate((0.5, 1.0)):
            rows = table[(table["method"] == m) & (table["noise_level"] == d)]
            np.testing.assert_allclose(error[i, k], rows["coverage_error"], rtol=1e-12)
    np.testing.assert_allclose(data["true_fraction"], (theta - lo) / (hi - lo), rtol=1e-12)
    np.testing.assert_allclose(data["posterior_mean_fraction"][0], data["true_fraction"], atol=1e-12)
    assert data["ranks"].shape == (2, 20, 23) and data["ranks"].max() <= 12

    drawn = {}
    save = calibration_figures.save_figure
    monkeypatch.setattr(calibration_figures, "save_figure", lambda fig, p: (drawn.setdefault(p, fig), save(fig, p)))
    paths = {k: str(tmp_path / f"{k}.png") for k in ("coverage_figure", "rank_figure", "recovery_figure")}
    calibration_figures.calibration_figures(out["figure_data"], **paths)
    coverage = drawn[paths["coverage_figure"]].axes
    assert [ax.get_title() for ax in coverage] == ["delta = 0.5", "delta = 1"]
    mean_line = [ln for ln in coverage[1].get_lines() if ln.get_label() == "NPE: marginal (mean of 23)"][0]
    np.testing.assert_array_equal(mean_line.get_ydata(), data["coverage"][1, 1].mean(axis=1))
    recovery = [ax for ax in drawn[paths["recovery_figure"]].axes if ax.get_visible()]
    assert len(recovery) == 23
    assert [ax.get_title() for ax in recovery[-4:]] == ["V0_v", "V0_r (non-id.)", "V0_pa (non-id.)", "V0_pv (non-id.)"]
    assert recovery[-1].title.get_color() == "tab:red" and recovery[0].title.get_color() == "k"
    np.testing.assert_array_equal(recovery[0].collections[0].get_offsets(),
                                  np.c_[data["true_fraction"][:, 0], data["posterior_mean_fraction"][0, :, 0]])
    assert sum(ax.get_visible() for ax in drawn[paths["rank_figure"]].axes) == 23
    assert all((tmp_path / f"{k}.pdf").is_file() for k in paths)
    imports = subprocess.run([sys.executable, "-c", "import sys, cvsim6.reporting.calibration_figures; print(sorted("
                              "m for m in sys.modules if m in ('torch', 'sbi', 'cvsim6.inference.calibration', "
                              "'matplotlib.pyplot') or m.startswith('cvsim6.studies')))"],
                             capture_output=True, text=True, check=True)
    assert imports.stdout.strip() == "[]", imports.stderr


def test_calibration_cases_share_rows_and_noise_draw_across_noise_levels(tmp_path):
    """The cases of every noise level are the same validation rows with the same unit noise
    draw, scaled by delta; a count outside the split is refused, naming it."""
    from training_helpers import synthetic

    from cvsim6.data.datasets import load_split
    from cvsim6.registry import noise_std
    from cvsim6.studies.cases import calibration_cases

    path = tmp_path / "validation.parquet"
    synthetic(50, 4).to_parquet(path)
    v_all, y_all = load_split(path)
    theta_a, y_a, obs_a = calibration_cases(str(path), 12, 0.5, seed=7)
    theta_b, y_b, obs_b = calibration_cases(str(path), 12, 2.0, seed=7)
    np.testing.assert_array_equal(theta_a, theta_b)
    np.testing.assert_array_equal(y_a, y_b)
    rows = [int(np.flatnonzero((v_all == t).all(axis=1))[0]) for t in theta_a]
    assert rows == sorted(set(rows)) and len(rows) == 12  # distinct rows, in split order
    np.testing.assert_array_equal(y_a, y_all[rows])
    np.testing.assert_allclose(obs_b - y_b, 4.0 * (obs_a - y_a), rtol=1e-12, atol=1e-9)
    unit = (obs_b - y_b) / (2.0 * noise_std())  # standard normal draws, 12 x 16
    assert abs(unit.mean()) < 0.3 and 0.7 < unit.std() < 1.3
    assert not np.array_equal(calibration_cases(str(path), 12, 0.5, seed=8)[0], theta_a)
    with pytest.raises(ValueError, match="n_cases = 51 must be between 1 and the 50"):
        calibration_cases(str(path), 51, 0.5, seed=7)
