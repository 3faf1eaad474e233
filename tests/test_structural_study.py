"""Error statistics on known numbers, out-of-domain decoded sets, trajectory panels. The structural
study end to end is checked in test_workflow_smoke.py."""
import json

import numpy as np
import pandas as pd
import pytest

from cvsim6.studies import evaluation
from cvsim6 import nets as networks
from cvsim6 import registry
from cvsim6.studies import structural as structural_study


def test_error_statistics_known_values():
    y = np.zeros((4, 16))
    yhat = np.zeros((4, 16))
    yhat[:, 0] = [1.0, -1.0, 3.0, -3.0]  # |err| 1, 1, 3, 3: mean 2, max 3, std 1
    yhat[2, 5] = np.nan  # a row with a NaN is left out everywhere
    s = evaluation.error_statistics(y, yhat)
    assert s.loc["Hr"].tolist() == pytest.approx([5 / 3, 3.0, np.std([1, 1, 3])])
    assert (s.loc["P_a_sys"] == 0).all()
    t = evaluation.error_table(s, {"mean": list(range(16)), "max": [0] * 16, "std": [0] * 16})
    assert list(t["Output"]) == list(registry.OUTPUT_NAMES) and t.loc[3, "Mean (paper)"] == 3


def test_relative_l2_errors():
    y = np.array([[3.0, 4.0] + [0.0] * 14, [1.0] + [0.0] * 15])
    yhat = y.copy()
    yhat[0, 0] += 0.5  # 0.5 / 5
    np.testing.assert_allclose(evaluation.relative_l2_errors(y, yhat), [0.1, 0.0])


def test_out_of_domain_decoded_sets_are_counted_not_fatal(tmp_path):
    """A decoder may extrapolate past the model's domain (C_v < 0 seen in a real run): such sets
    are counted and left out; the others give the known answer (y* from the same parameters)."""
    from cvsim6.data import datasets
    from cvsim6.model import solver

    sim = {"steps_per_cycle": solver.DEFAULT_STEPS_PER_CYCLE, "n_cycles": solver.DEFAULT_N_CYCLES,
           "window_cycles": solver.DEFAULT_WINDOW_CYCLES}
    v = np.repeat(registry.default_parameters()[None], 4, axis=0)
    v[1, registry.PARAMETER_INDEX["C_v"]] = -41.6
    v[3, registry.PARAMETER_INDEX["V0_v"]] *= 1.01  # a different, valid set
    y_star, st = solver.simulate_batch(v[:1])
    obs = tmp_path / "obs.csv"
    pd.DataFrame({"Output": list(registry.OUTPUT_NAMES), "y*": y_star[0]}).to_csv(obs, index=False)
    samples = tmp_path / "samples.parquet"
    datasets.write_dataset(pd.DataFrame(v, columns=list(registry.PARAMETER_NAMES)), samples)
    csv = tmp_path / "rec.csv"
    emulator = tmp_path / "emulator.pt"
    networks.save_model(_constant_emulator(1.01 * y_star[0]), emulator)
    structural_study.manifold_reconstruction(str(samples), str(obs), csv=str(csv), summary=str(tmp_path / "rec.json"),
                                             md=str(tmp_path / "rec.md"), figure=str(tmp_path / "rec.png"),
                                             simulator=sim, n_reconstruct=3, n_traces=3, emulator=str(emulator))
    summary = json.loads((tmp_path / "rec.json").read_text())
    assert summary["outside_domain"] == 1 and summary["flagged"] == 0
    assert summary["max_rel_l2_error"] < 1e-12 and summary["max_rel_error_per_output"] < 1e-12  # rows 0 and 2 are y*'s own parameters
    # the emulator answers 1.01 y* everywhere: 1% from y* (the decoder's share), and 1% from f(v) = y*
    assert summary["max_rel_l2_error_decoder"] == pytest.approx(0.01, rel=1e-5)
    assert summary["max_rel_l2_error_emulator"] == pytest.approx(0.01, rel=1e-5)
    assert "of which the decoder" in (tmp_path / "rec.md").read_text()
    structural_study.manifold_svd_figure(str(samples), str(tmp_path / "svd.png"), str(tmp_path / "svd.csv"),
                                         str(tmp_path / "svd.json"))
    svd = json.loads((tmp_path / "svd.json").read_text())
    assert svd["n_samples"] == 3 and svd["outside_domain"] == 1


def test_max_of_random_subsets_follows_the_exact_distribution():
    """The max of a random k-subset of n distinct values has P(max <= the j-th smallest) =
    C(j, k) / C(n, k); with k >= n every draw is the overall max; a seed repeats its draws."""
    from math import comb

    e = np.random.default_rng(3).permutation(np.arange(20.0))  # the values 0..19, any order
    m = evaluation.max_of_random_subsets(e, 5, 20000, seed=1)
    for j in (5, 10, 15, 19):
        assert np.mean(m <= j - 1) == pytest.approx(comb(j, 5) / comb(20, 5), abs=0.015)
    assert np.array_equal(m, evaluation.max_of_random_subsets(e, 5, 20000, seed=1))
    assert (evaluation.max_of_random_subsets(e, 25, 10) == 19.0).all()
    with pytest.raises(ValueError, match="subset and resamples must be >= 1, got 0"):
        evaluation.max_of_random_subsets(e, 0, 10)


def test_reconstruction_spread_is_the_order_statistics_and_leaves_the_headline(tmp_path):
    """Six decoded sets, the headline over the first three: the max of a random three of the six
    is the 6th smallest error with probability 1/2, the 4th or less with 1/4, so the 90% quantile
    is the largest error and the 10% one the 4th smallest; the first-three headline and its table
    are those of a run without the spread, bit for bit."""
    from cvsim6.data import datasets
    from cvsim6.model import solver

    sim = {"steps_per_cycle": solver.DEFAULT_STEPS_PER_CYCLE, "n_cycles": solver.DEFAULT_N_CYCLES,
           "window_cycles": solver.DEFAULT_WINDOW_CYCLES}
    v = np.repeat(registry.default_parameters()[None], 6, axis=0)
    v[:, registry.PARAMETER_INDEX["V0_v"]] *= 1.0 + np.array([0.0, 0.02, 0.005, 0.03, 0.01, 0.04])
    y, _ = solver.simulate_batch(v)
    obs = tmp_path / "obs.csv"
    pd.DataFrame({"Output": list(registry.OUTPUT_NAMES), "y*": y[0]}).to_csv(obs, index=False)
    samples = tmp_path / "samples.parquet"
    datasets.write_dataset(pd.DataFrame(v, columns=list(registry.PARAMETER_NAMES)), samples)
    errors = np.sort(evaluation.relative_l2_errors(np.broadcast_to(y[0], y.shape), y))
    out = {}
    for name, n_spread in (("plain", 0), ("spread", 6)):
        structural_study.manifold_reconstruction(
            str(samples), str(obs), csv=str(tmp_path / f"{name}.csv"), summary=str(tmp_path / f"{name}.json"),
            md=str(tmp_path / f"{name}.md"), figure=str(tmp_path / f"{name}.png"), simulator=sim, n_reconstruct=3,
            n_traces=3, n_spread=n_spread, spread_resamples=500, seed=4)
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    spread = out["spread"].pop("max_rel_l2_error_resampled")
    assert out["spread"] == out["plain"]
    assert (tmp_path / "spread.csv").read_bytes() == (tmp_path / "plain.csv").read_bytes()
    first3 = evaluation.relative_l2_errors(np.broadcast_to(y[0], (3, 16)), y[:3])
    assert out["plain"]["max_rel_l2_error"] == pytest.approx(first3.max(), rel=1e-12)
    assert spread["n_simulated"] == 6 and spread["subset"] == 3 and spread["outside_domain"] == 0
    assert spread["q90"] == pytest.approx(errors[5], rel=1e-12)
    assert spread["q10"] == pytest.approx(errors[3], rel=1e-12)
    assert spread["median_rel_l2_error"] == pytest.approx(np.median(errors), rel=1e-12)
    assert "10/50/90% quantiles" in (tmp_path / "spread.md").read_text()


def _constant_emulator(y: np.ndarray):
    """An emulator whose answer is ``y`` (16,) for every parameter set: all weights zero, the
    output scaler's mean at ``y``."""
    import torch

    emu = networks.Emulator(8, 2)
    with torch.no_grad():
        for p in emu.parameters():
            p.zero_()
    emu.y_scaler.mean.copy_(torch.as_tensor(y))
    return emu


def test_reconstruction_error_sources_known_values():
    """y* = 10 e_0; the emulator answers y* + 4 e_1 for both sets, the simulator y* for the
    first and y* + 3 e_1 for the second: decoder share 4/10 for both, emulator share 4/10 and
    ||(0, 1)|| / ||(10, 3)||."""
    y_star = np.zeros(16)
    y_star[0] = 10.0
    y_sim = np.array([y_star, y_star])
    y_sim[1, 1] = 3.0
    y_emu = np.array([y_star, y_star])
    y_emu[:, 1] = 4.0
    s = structural_study.reconstruction_error_sources(y_star, y_sim, y_emu)
    assert s["max_rel_l2_error_decoder"] == pytest.approx(0.4) and s["median_rel_l2_error_decoder"] == pytest.approx(0.4)
    assert s["max_rel_l2_error_emulator"] == pytest.approx(0.4)
    assert s["median_rel_l2_error_emulator"] == pytest.approx((0.4 + 1 / np.hypot(10, 3)) / 2)


def test_trajectory_panels_draw_every_set_and_target():
    """Each of the 4 panels gets one curve per parameter set and a dashed line per observed
    target, also when handed ``axes.flat`` (an iterator)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsim6.model import solver

    sim = {"steps_per_cycle": 200, "n_cycles": 6, "window_cycles": 2}
    v = np.repeat(registry.default_parameters()[None], 3, axis=0)
    v[1, registry.PARAMETER_INDEX["C_a"]] *= 1.2
    v[2, registry.PARAMETER_INDEX["C_v"]] = -1.0  # outside the domain: skipped
    y_star = solver.simulate_batch(v[:1])[0][0]
    observed = np.ones(16, bool)
    observed[registry.OUTPUT_INDEX["P_a_dia"]] = False
    fig, axes = plt.subplots(2, 2)
    structural_study._trajectory_panels(axes.flat, v, y_star, sim, ["r", "g", "b"], observed=observed)
    dashed = [sum(ln.get_linestyle() == "--" for ln in ax.lines) for ax in axes.flat]
    curves = [sum(ln.get_linestyle() == "-" for ln in ax.lines) for ax in axes.flat]
    assert curves == [2, 2, 2, 2] and dashed == [1, 2, 2, 2]
    assert [ax.get_ylabel() for ax in axes.flat] == ["P_a (mmHg)", "P_r (mmHg)", "P_pa (mmHg)", "V_l (mL)"]
    plt.close(fig)
