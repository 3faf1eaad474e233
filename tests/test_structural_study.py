"""Error statistics on known numbers, out-of-domain decoded sets, the data files behind the figures
(traces, parallel coordinates, SVD, Jacobian spectra) and the figures drawn from them. The structural
study end to end is checked in test_workflow_smoke.py."""
import json

import numpy as np
import pandas as pd
import pytest

from cvsim6.studies import evaluation
from cvsim6 import nets as networks
from cvsim6 import registry
from cvsim6.data import datasets
from cvsim6.model import solver
from cvsim6.reporting import structural_figures
from cvsim6.studies import structural as structural_study

#: A short simulator schedule for the trace tests (outputs within 0.5% of the default's).
SHORT = {"steps_per_cycle": 200, "n_cycles": 6, "window_cycles": 2}
DEFAULT_SIM = {"steps_per_cycle": solver.DEFAULT_STEPS_PER_CYCLE, "n_cycles": solver.DEFAULT_N_CYCLES,
               "window_cycles": solver.DEFAULT_WINDOW_CYCLES}


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
    sim = DEFAULT_SIM
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
                                             md=str(tmp_path / "rec.md"), traces=str(tmp_path / "rec_traces.csv"),
                                             simulator=sim, n_reconstruct=3, n_traces=3, emulator=str(emulator))
    summary = json.loads((tmp_path / "rec.json").read_text())
    assert summary["outside_domain"] == 1 and summary["flagged"] == 0
    assert summary["max_rel_l2_error"] < 1e-12 and summary["max_rel_error_per_output"] < 1e-12  # rows 0 and 2 are y*'s own parameters
    # the emulator answers 1.01 y* everywhere: 1% from y* (the decoder's share), and 1% from f(v) = y*
    assert summary["max_rel_l2_error_decoder"] == pytest.approx(0.01, rel=1e-5)
    assert summary["max_rel_l2_error_emulator"] == pytest.approx(0.01, rel=1e-5)
    assert "of which the decoder" in (tmp_path / "rec.md").read_text()
    # traces of the first 3 sets: set 1 is outside the domain; sets 0 and 2 are y*'s own parameters
    traces = pd.read_csv(tmp_path / "rec_traces.csv")
    assert sorted(traces["set"].unique()) == [0, 2]
    for _, rows in traces.groupby("set"):
        assert rows["P_a"].max() == pytest.approx(y_star[0, registry.OUTPUT_INDEX["P_a_sys"]], rel=5e-3)
        assert rows["P_a"].min() == pytest.approx(y_star[0, registry.OUTPUT_INDEX["P_a_dia"]], rel=1e-3)
    structural_study.manifold_svd_modes(str(samples), str(tmp_path / "svd.csv"), str(tmp_path / "svd.json"))
    svd = json.loads((tmp_path / "svd.json").read_text())
    assert svd["n_samples"] == 3 and svd["outside_domain"] == 1
    # sets 0, 2, 3 differ in V0_v only: one standardized column, norm sqrt(3), one mode
    table = pd.read_csv(tmp_path / "svd.csv")
    np.testing.assert_allclose(table["singular_value"], [np.sqrt(3), 0, 0], atol=1e-12)
    np.testing.assert_allclose(table["cumulative_energy"], [1, 1, 1])
    assert svd["modes"] == 1 and svd["energy"] == pytest.approx(1.0)


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
    sim = DEFAULT_SIM
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
            md=str(tmp_path / f"{name}.md"), traces=str(tmp_path / f"{name}_traces.csv"), simulator=sim,
            n_reconstruct=3, n_traces=3, n_spread=n_spread, spread_resamples=500, seed=4)
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    spread = out["spread"].pop("max_rel_l2_error_resampled")
    assert out["spread"] == out["plain"]
    assert (tmp_path / "spread.csv").read_bytes() == (tmp_path / "plain.csv").read_bytes()
    assert (tmp_path / "spread_traces.csv").read_bytes() == (tmp_path / "plain_traces.csv").read_bytes()
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


def test_last_cycle_traces_match_the_simulated_outputs():
    """The traces of each set inside the domain span one cycle (t/T from 0 to 1), and their
    pressure extremes are that set's systolic/diastolic outputs from the batch simulator."""
    v = np.repeat(registry.default_parameters()[None], 3, axis=0)
    v[1, registry.PARAMETER_INDEX["C_a"]] *= 1.2
    v[2, registry.PARAMETER_INDEX["C_v"]] = -1.0  # outside the domain: left out
    traces = structural_study.last_cycle_traces(v, SHORT)
    assert list(traces.columns) == ["set", "t_over_T", "P_a", "P_r", "P_pa", "V_l"]
    assert sorted(traces["set"].unique()) == [0, 1]
    y, st = solver.simulate_batch(v[:2], **SHORT)
    assert (st == 0).all()
    for i, rows in traces.groupby("set"):
        assert rows["t_over_T"].iloc[0] == 0.0 and rows["t_over_T"].iloc[-1] == pytest.approx(1.0)
        assert rows["t_over_T"].is_monotonic_increasing
        for q in ("P_a", "P_r", "P_pa"):
            assert rows[q].max() == pytest.approx(y[i, registry.OUTPUT_INDEX[f"{q}_sys"]], rel=5e-3)
            assert rows[q].min() == pytest.approx(y[i, registry.OUTPUT_INDEX[f"{q}_dia"]], rel=1e-3)
    assert traces.loc[traces["set"] == 1, "P_a"].max() < traces.loc[traces["set"] == 0, "P_a"].max()  # stiffer C_a
    empty = structural_study.last_cycle_traces(v[2:], SHORT)
    assert empty.empty and list(empty.columns) == list(traces.columns)


def _synthetic_traces(sets, n_points: int = 5) -> pd.DataFrame:
    """Traces of ``sets``: t/T on [0, 1], every quantity equal to set + t/T."""
    t = np.linspace(0.0, 1.0, n_points)
    return pd.concat([pd.DataFrame({"set": i, "t_over_T": t, "P_a": i + t, "P_r": i + t, "P_pa": i + t,
                                    "V_l": i + t}) for i in sets], ignore_index=True)


def _observation(tmp_path) -> tuple[str, np.ndarray]:
    y_star = np.arange(1.0, 17.0)
    path = tmp_path / "obs.csv"
    pd.DataFrame({"Output": list(registry.OUTPUT_NAMES), "y*": y_star}).to_csv(path, index=False)
    return str(path), y_star


@pytest.fixture
def drawn(monkeypatch):
    """The figures the structural figure functions would save, in order."""
    figures = []
    monkeypatch.setattr(structural_figures, "save_figure", lambda fig, path: figures.append(fig))
    return figures


def test_trajectory_figures_draw_every_set_and_target(tmp_path, drawn):
    """Reconstruction: one curve per traced set (viridis by set index) and both targets per
    panel. Missing data: one colour per completion, dashed lines at the observed targets only."""
    from matplotlib import colormaps

    obs, y_star = _observation(tmp_path)
    _synthetic_traces([0, 2]).to_csv(tmp_path / "rec.csv", index=False)
    (tmp_path / "rec.json").write_text(json.dumps({"n": 7}))
    structural_figures.manifold_trajectories_figure(str(tmp_path / "rec.csv"), obs, str(tmp_path / "rec.json"),
                                                    "unused.png", n_traces=3)
    fig = drawn.pop()
    axes = fig.axes
    assert [sum(ln.get_linestyle() == "-" for ln in ax.lines) for ax in axes] == [2, 2, 2, 2]
    assert [sum(ln.get_linestyle() == "--" for ln in ax.lines) for ax in axes] == [2, 2, 2, 2]
    assert [ax.get_ylabel() for ax in axes] == ["P_a (mmHg)", "P_r (mmHg)", "P_pa (mmHg)", "V_l (mL)"]
    curves = [ln for ln in axes[0].lines if ln.get_linestyle() == "-"]
    viridis = colormaps["viridis"]
    assert [ln.get_color() for ln in curves] == [viridis(0.0), viridis(1.0)]  # sets 0 and 2 of 3
    np.testing.assert_allclose(curves[1].get_ydata(), 2 + np.linspace(0, 1, 5))
    targets = sorted(ln.get_ydata()[0] for ln in axes[0].lines if ln.get_linestyle() == "--")
    assert targets == sorted(y_star[[registry.OUTPUT_INDEX["P_a_sys"], registry.OUTPUT_INDEX["P_a_dia"]]])
    assert fig._suptitle.get_text().startswith("The first 3 of 7 decoded parameter sets")

    missing = _synthetic_traces([0, 1])
    traces = pd.concat([missing.assign(completion=1), missing.assign(completion=2)], ignore_index=True)
    traces.to_csv(tmp_path / "miss.csv", index=False)
    structural_figures.missing_data_figure(str(tmp_path / "miss.csv"), obs, "unused.png", missing=["P_a_dia"],
                                           top_k=2, n_latent=2)
    fig = drawn.pop()
    axes = fig.axes
    assert [sum(ln.get_linestyle() == "-" and len(ln.get_xdata()) > 0 for ln in ax.lines) for ax in axes] == [4] * 4
    # the observed targets once per completion (P_a_dia is missing)
    assert [sum(ln.get_linestyle() == "--" for ln in ax.lines) for ax in axes] == [2, 4, 4, 4]
    drawn_targets = {ln.get_ydata()[0] for ax in axes for ln in ax.lines if ln.get_linestyle() == "--"}
    shown = ("P_a_sys", "P_r_sys", "P_r_dia", "P_pa_sys", "P_pa_dia", "V_l_sys", "V_l_dia")
    assert drawn_targets == {y_star[registry.OUTPUT_INDEX[n]] for n in shown}
    tab10 = colormaps["tab10"].colors
    colors = [ln.get_color() for ln in axes[1].lines if ln.get_linestyle() == "-"]
    assert colors == [tab10[0]] * 2 + [tab10[1]] * 2
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == ["completion 1", "completion 2"]


def test_trajectory_figure_saves_png_and_pdf(tmp_path):
    """The figure function writes the PNG at the path given and a PDF beside it."""
    obs, _ = _observation(tmp_path)
    _synthetic_traces([0, 1, 2]).to_csv(tmp_path / "rec.csv", index=False)
    (tmp_path / "rec.json").write_text(json.dumps({"n": 3}))
    png = tmp_path / "out" / "manifold_trajectories.png"
    structural_figures.manifold_trajectories_figure(str(tmp_path / "rec.csv"), obs, str(tmp_path / "rec.json"),
                                                    str(png), n_traces=3)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert png.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"


def test_parallel_coordinates_data_and_figure(tmp_path, drawn):
    """The lines are the first n in-domain samples; the axis limits are the prior bounds widened
    by 5% of their width (Hr: 0.7-1.3 x default -> 0.67-1.33 x; compliances 0.5-1.5 -> 0.45-1.55)."""
    v = np.repeat(registry.default_parameters()[None], 4, axis=0)
    v[:, registry.PARAMETER_INDEX["R_l_in"]] *= [1.0, 1.1, 1.2, 1.25]
    v[1, registry.PARAMETER_INDEX["C_v"]] = -1.0  # outside the domain
    samples = tmp_path / "samples.parquet"
    datasets.write_dataset(pd.DataFrame(v, columns=list(registry.PARAMETER_NAMES)), samples)
    prior = {"default": [0.7, 1.3], "kinds": {"compliance": [0.5, 1.5]}}
    lines, summary = tmp_path / "lines.csv", tmp_path / "pc.json"
    structural_study.parallel_coordinates_data(str(samples), str(lines), str(summary), prior, n_lines=2)
    np.testing.assert_array_equal(pd.read_csv(lines)[list(registry.PARAMETER_NAMES)].to_numpy(), v[[0, 2]])
    info = json.loads(summary.read_text())
    assert info["lines"] == 2 and info["outside_domain"] == 1
    default = registry.PARAMETER_BY_NAME
    assert info["axis_limits"]["Hr"] == pytest.approx([0.67 * default["Hr"].default, 1.33 * default["Hr"].default])
    assert info["axis_limits"]["C_a"] == pytest.approx([0.45 * default["C_a"].default, 1.55 * default["C_a"].default])

    structural_figures.parallel_coordinates_figure(str(lines), str(summary), "unused.png")
    fig = drawn.pop()
    top, bottom = fig.axes
    assert [t.get_text() for t in top.get_xticklabels()] == list(registry.PARAMETER_NAMES[:12])
    assert [t.get_text() for t in bottom.get_xticklabels()] == list(registry.PARAMETER_NAMES[11:])
    # the priors are symmetric about the defaults: a default sits mid-axis; R_l_in (x 1.2 in the
    # second line) is the last axis of the top row and the first of the bottom row
    for ax, j in ((top, 11), (bottom, 0)):
        polylines = [ln for ln in ax.lines if len(ln.get_xdata()) == 12]
        assert len(polylines) == 2
        np.testing.assert_allclose(polylines[0].get_ydata(), 0.5, atol=1e-12)
        u = np.full(12, 0.5)
        u[j] = (1.2 - 0.67) / 0.66
        np.testing.assert_allclose(polylines[1].get_ydata(), u, atol=1e-12)
    assert "2 decoded parameter sets" in fig._suptitle.get_text() and "1 sets outside" in fig._suptitle.get_text()


def test_manifold_svd_figure_marks_the_modes(tmp_path, drawn):
    pd.DataFrame({"mode": [1, 2, 3], "singular_value": [4.0, 2.0, 0.5],
                  "cumulative_energy": [0.8, 0.99, 1.0]}).to_csv(tmp_path / "svd.csv", index=False)
    (tmp_path / "svd.json").write_text(json.dumps({"n_samples": 1234, "level": 0.99, "modes": 2, "energy": 0.99}))
    structural_figures.manifold_svd_figure(str(tmp_path / "svd.csv"), str(tmp_path / "svd.json"), "unused.png")
    fig = drawn.pop()
    a, b = fig.axes
    np.testing.assert_array_equal(a.lines[0].get_ydata(), [4.0, 2.0, 0.5])
    assert b.texts[0].get_text() == "2 modes: 99.00%"
    assert fig._suptitle.get_text().startswith("SVD of 1,234 standardized parameter sets")


def test_jacobian_spectra_give_the_ranks_in_the_summary(tmp_path, drawn):
    """The spectra written are descending, one row per point; counting sigma_k > rtol sigma_1 in
    each row gives the summary's ranks; the figure draws each row divided by its first value."""
    v = np.repeat(registry.default_parameters()[None], 2, axis=0)
    v[1, registry.PARAMETER_INDEX["R_a"]] *= 1.1
    samples = tmp_path / "samples.parquet"
    datasets.write_dataset(pd.DataFrame(v, columns=list(registry.PARAMETER_NAMES)), samples)
    prior = {"default": [0.7, 1.3], "kinds": {"compliance": [0.5, 1.5]}}
    out = {k: str(tmp_path / f"jac.{k}") for k in ("csv", "json", "md")}
    spectra = tmp_path / "spectra.csv"
    structural_study.jacobian_check(str(samples), out["csv"], out["json"], out["md"], str(spectra), prior, SHORT,
                                    n_points=2, rel_step=1e-4, rank_rtol=1e-3)
    sv = pd.read_csv(spectra)
    assert list(sv.columns) == [f"sigma_{k}" for k in range(1, 17)] and len(sv) == 2
    s = sv.to_numpy()
    assert (np.diff(s, axis=1) <= 0).all() and (s[:, 0] > 0).all()
    ranks = (s > 1e-3 * s[:, :1]).sum(axis=1)
    info = json.loads((tmp_path / "jac.json").read_text())
    assert info["points"] == 2 and info["median_rank"] == float(np.median(ranks))
    assert info["rank_counts"] == {str(r): int((ranks == r).sum()) for r in np.unique(ranks)}

    structural_figures.jacobian_spectra_figure(str(spectra), "unused.png", rank_rtol=1e-3)
    ax = drawn.pop().axes[0]
    np.testing.assert_allclose(ax.lines[1].get_ydata(), s[1] / s[1, 0])
    assert ax.lines[2].get_ydata()[0] == 1e-3 and ax.get_title() == "Jacobian spectra at 2 points of the manifold of y*"


def test_missing_data_writes_the_traces_of_each_completion(tmp_path, monkeypatch):
    """With the flow and decoder replaced by known answers (2 completions x 2 draws, one draw
    outside the domain), the traces hold every in-domain draw under its completion and the
    summary's error is the relative l2 error over the observed entries, recomputed here."""
    v = np.repeat(registry.default_parameters()[None], 4, axis=0).reshape(2, 2, -1)
    v[0, 1, registry.PARAMETER_INDEX["C_a"]] *= 1.1
    v[1, 0, registry.PARAMETER_INDEX["V0_v"]] *= 1.01
    v[1, 1, registry.PARAMETER_INDEX["C_v"]] = -1.0
    y, _ = solver.simulate_batch(v[0, :1], **SHORT)
    obs = tmp_path / "obs.csv"
    pd.DataFrame({"Output": list(registry.OUTPUT_NAMES), "y*": y[0]}).to_csv(obs, index=False)
    monkeypatch.setattr(structural_study, "load_model", lambda path: None)
    monkeypatch.setattr(structural_study.inversion, "complete_missing",
                        lambda flow, y_obs, n, top_k, seed: (np.repeat(np.nan_to_num(y_obs)[None], top_k, 0),
                                                              np.array([-1.0, -2.0])))
    monkeypatch.setattr(structural_study.inversion, "decode_latent", lambda *args, **kwargs: v)
    missing = ["P_a_dia", "SVR"]
    out = {k: str(tmp_path / f"miss.{k}") for k in ("csv", "json", "md")}
    structural_study.missing_data("flow.pt", "ed.pt", str(obs), out["csv"], out["json"], out["md"],
                                  str(tmp_path / "traces.csv"), SHORT, missing, n_flow_samples=10, top_k=2,
                                  n_latent=2, seed=0)
    traces = pd.read_csv(tmp_path / "traces.csv")
    assert list(traces.columns) == ["completion", "set", "t_over_T", "P_a", "P_r", "P_pa", "V_l"]
    assert sorted(traces.groupby(["completion", "set"]).groups) == [(1, 0), (1, 1), (2, 0)]
    info = json.loads((tmp_path / "miss.json").read_text())
    assert info["outside_domain"] == 1
    observed = np.array([n not in missing for n in registry.OUTPUT_NAMES])
    y_sets, _ = solver.simulate_batch(v.reshape(4, -1)[:3], **SHORT)
    errors = np.linalg.norm(y_sets[:, observed] - y[0, observed], axis=1) / np.linalg.norm(y[0, observed])
    assert info["max_rel_l2_error_observed"] == pytest.approx(errors.max(), rel=1e-9)
    assert list(pd.read_csv(out["csv"])["rank"]) == [1, 2]
