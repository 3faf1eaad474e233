"""The benchmark helpers in benchmarks/ (scripts, not package code): their arithmetic."""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cvsim6 import registry

ROOT = Path(__file__).resolve().parents[1]
HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _bench(path: Path, wall: float, cpu: float, rss: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(HEADER + f"{wall}\t0:00:00\t{rss}\t0\t0\t0\t0\t0\t100\t{cpu}\n")


def test_workflow_times_sums_jobs_per_rule_and_source(tmp_path):
    wt = _load("workflow_times")
    _bench(tmp_path / "train_flow" / "ehr_delta0.5.tsv", 300.0, 280.0, 600.0)
    _bench(tmp_path / "train_flow" / "ehr_delta1.tsv", 310.0, 290.0, 650.0)
    _bench(tmp_path / "train_emulator" / "structural.tsv", 900.0, 880.0, 500.0)
    _bench(tmp_path / "ehr_patients.tsv", 2.0, 1.5, 100.0)
    _bench(tmp_path / "published" / "convert_published" / "ehr.tsv", 3.0, 2.0, 200.0)
    (tmp_path / "results").mkdir()  # files other than TSV are not jobs
    (tmp_path / "results" / "training_x.csv").write_text("a\n1\n")

    jobs = wt.job_times(tmp_path)
    assert len(jobs) == 5
    pub = jobs[jobs["source"] == "published"]
    assert list(pub["rule"]) == ["convert_published"] and list(pub["job"]) == ["ehr"]
    flow = jobs[jobs["rule"] == "train_flow"].set_index("job")
    assert flow.loc["ehr_delta0.5", "cpu_s"] == 280.0 and flow.loc["ehr_delta1", "wall_s"] == 310.0

    table = wt.rule_times(jobs[jobs["source"] == "trained"]).set_index("rule")
    assert list(table.index) == ["train_emulator", "train_flow", "ehr_patients", "total"]  # by CPU seconds
    assert table.loc["train_flow", "jobs"] == 2
    assert table.loc["train_flow", "cpu_s"] == pytest.approx(570.0)
    assert table.loc["train_flow", "longest_wall_s"] == 310.0
    assert table.loc["train_flow", "max_rss_mb"] == 650.0
    assert table.loc["total", "cpu_s"] == pytest.approx(880.0 + 570.0 + 1.5)
    assert table.loc["total", "wall_s"] == pytest.approx(900.0 + 610.0 + 2.0)
    assert table["cpu_share"].iloc[:-1].sum() == pytest.approx(1.0)

    # the run's elapsed time: first start (end - wall) to last end, per source
    for name, end in [("train_flow/ehr_delta0.5", 1000.0), ("train_flow/ehr_delta1", 1400.0),
                      ("train_emulator/structural", 1100.0), ("ehr_patients", 1402.0),
                      ("published/convert_published/ehr", 5000.0)]:
        os.utime(tmp_path / f"{name}.tsv", (end, end))
    spans = wt.run_spans(wt.job_times(tmp_path)).set_index("source")
    assert spans.loc["trained", "elapsed_s"] == pytest.approx(1402.0 - (1100.0 - 900.0))
    assert spans.loc["trained", "elapsed_min"] == pytest.approx(1202.0 / 60)
    assert spans.loc["published", "elapsed_s"] == pytest.approx(3.0)
    assert spans.loc["trained", "jobs"] == 4 and spans.loc["trained", "cpu_s"] == pytest.approx(1451.5)
    # busy time: the union of [200, 1100], [700, 1000], [1090, 1400] and [1400, 1402], no gap
    assert spans.loc["trained", "busy_s"] == pytest.approx(1202.0)

    # a run stopped and resumed: the gap between its two parts is elapsed, not busy
    _bench(tmp_path / "train_flow" / "ehr_delta2.tsv", 100.0, 90.0, 650.0)
    os.utime(tmp_path / "train_flow" / "ehr_delta2.tsv", (3000.0, 3000.0))
    spans = wt.run_spans(wt.job_times(tmp_path)).set_index("source")
    assert spans.loc["trained", "elapsed_s"] == pytest.approx(3000.0 - 200.0)
    assert spans.loc["trained", "busy_s"] == pytest.approx(1202.0 + 100.0)
    assert spans.loc["trained", "busy_min"] == pytest.approx(1302.0 / 60)
    assert spans.loc["published", "busy_s"] == pytest.approx(3.0)


def test_workflow_times_rejects_a_file_that_is_not_a_benchmark(tmp_path):
    wt = _load("workflow_times")
    (tmp_path / "notes.tsv").write_text("a\tb\n1\t2\n")
    with pytest.raises(ValueError, match="notes.tsv"):
        wt.job_times(tmp_path)
    with pytest.raises(FileNotFoundError, match="no Snakemake benchmark files"):
        wt.job_times(tmp_path / "empty")


def _card(root: Path, values: dict[str, tuple[float, float]]) -> Path:
    rows = [{"Headline": h, "Paper": p, "Paper section": "x", "trained": v, "trained / paper": v / p,
             "trained file": "f"} for h, (p, v) in values.items()]
    path = root / "results" / "report" / "reproduction.csv"
    path.parent.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(path, index=False)
    return root


def test_seed_spread_puts_runs_side_by_side(tmp_path):
    tool = _load("seed_spread")
    a = _card(tmp_path / "a", {"table 3": (1.0, 1.6), "l2 (%)": (0.14, 0.28), "lambda_1": (-521.0, -520.0)})
    b = _card(tmp_path / "b", {"l2 (%)": (0.14, 0.42), "table 3": (1.0, 1.2), "lambda_1": (-521.0, -522.0)})
    table = tool.seed_spread({"s1": a, "s2": b})
    assert list(table.index) == ["table 3", "l2 (%)", "lambda_1"]  # the first run's order
    assert table.loc["l2 (%)", "s2"] == pytest.approx(0.42) and table.loc["l2 (%)", "s1 / paper"] == pytest.approx(2.0)
    assert table.loc["table 3", "spread"] == pytest.approx(1.6 / 1.2)
    assert table.loc["l2 (%)", "spread"] == pytest.approx(3.0 / 2.0)
    assert table.loc["lambda_1", "spread"] == pytest.approx(522.0 / 520.0)
    c = _card(tmp_path / "c", {"table 3": (1.0, 1.6), "l2 (%)": (0.15, 0.28), "lambda_1": (-521.0, -520.0)})
    with pytest.raises(ValueError, match="'s3'"):
        tool.seed_spread({"s1": a, "s3": c})
    with pytest.raises(FileNotFoundError, match="'s4'"):
        tool.seed_spread({"s1": a, "s4": tmp_path / "nowhere"})


def test_machine_speed_estimate_counts_copies_candidates_and_the_structural_chain():
    tool = _load("machine_speed")
    # the paper's split of a 54,000-set study: 4,000 validation, of the rest 3/4 train, 1/4 test
    assert tool.split_sizes({"n_samples": 54000, "split": {"validation": 4000, "train_fraction": 0.75}}) == (37500, 12500)
    ed = {"epochs": 7200, "restarts": 3, "restart_epochs": 500}
    assert tool.schedule_epochs(ed) == 7200 + 2 * 500
    assert tool.schedule_epochs({"epochs": 400}) == 400
    training = {"studies": {
        "structural": {"noise_levels": [0.0], "emulator": {"epochs": 5400}, "encoder_decoder": ed},
        "ehr": {"noise_levels": [0.25, 0.5, 1.0, 2.0], "flow": {"epochs": 400}}}}
    per_epoch = {("structural", "emulator"): 1.0, ("structural", "encoder_decoder"): 2.0, ("ehr", "flow"): 0.5}
    df, total, wall = tool.estimate(per_epoch, training, cores=2)
    cpu = df.set_index(["study", "network"])["cpu_s"]
    assert cpu[("structural", "encoder_decoder")] == 2.0 * 8200 and cpu[("ehr", "flow")] == 4 * 400 * 0.5
    assert total == 5400 + 16400 + 800
    # 2 cores: the three candidates in two rounds of 500 epochs, then 6,700 more; longer than total / 2
    assert wall == 5400 + 2.0 * (2 * 500 + 6700)
    assert tool.estimate(per_epoch, training, cores=3)[2] == 5400 + 2.0 * (500 + 6700)
    assert tool.estimate(per_epoch, training, cores=1)[2] == total
    # a restart target: up to max_restarts candidates, the extra ones one at a time after the first round
    ed.update(restart_target=0.05, max_restarts=6)
    assert tool.candidates(ed) == 3 and tool.candidates(ed, screened=True) == 6
    assert tool.schedule_epochs(ed) == 8200 and tool.schedule_epochs(ed, screened=True) == 7200 + 5 * 500
    _, total_s, wall_s = tool.estimate(per_epoch, training, cores=2, screened=True)
    assert total_s == total + 2.0 * 3 * 500
    assert wall_s == 5400 + 2.0 * ((2 + 3) * 500 + 6700)
    assert tool.estimate(per_epoch, training, cores=2)[1:] == (total, wall)  # unscreened: as without a target


def test_batched_copies_compute_each_copys_loss_and_gradient():
    """The batched flow and encoder/decoder of benchmarks/batched_copies.py are the copies: each
    copy's loss equals its own network's, a change to one copy's weights moves that copy's loss
    only, and the gradient of the summed loss is each network's own gradient, stacked."""
    import torch

    from cvsim6 import nets as nw

    bc = _load("batched_copies")
    torch.manual_seed(0)
    flows = [nw.RealNVP(hidden=6, blocks=3, layers_per_block=3, batchnorm=True) for _ in range(3)]
    grouped = bc.GroupedFlow(flows)
    y = torch.randn(3, 32, 16, dtype=torch.float32)
    own = torch.stack([nw.flow_nll(f, y[k]) for k, f in enumerate(flows)])
    batched = grouped.nll(y)
    torch.testing.assert_close(batched, own, rtol=1e-5, atol=1e-5)
    batched.sum().backward()
    own.sum().backward()
    torch.testing.assert_close(grouped.layers[0]["s"][0].weight.grad[1], flows[1].layers[0].s[0].weight.grad.t(),
                               rtol=1e-4, atol=1e-6)
    with torch.no_grad():
        grouped.layers[0]["s"][0].weight[2] += 0.1
        moved = grouped.nll(y) != own
    assert moved.tolist() == [False, False, True]
    eds = [nw.EncoderDecoder(latent_dim=4, encoder_hidden=8, encoder_layers=3, decoder_hidden=8, decoder_layers=3)
           for _ in range(2)]
    emulator = nw.Emulator(8, 3).requires_grad_(False)
    v, y, eps = torch.randn(2, 16, 23), torch.randn(2, 16, 16), torch.randn(2, 16, 4)
    own = torch.stack([nw.encoder_decoder_loss(m, v[k], y[k], eps[k], emulator, 1000.0, 1.0, 10.0, reduction="mse")[0]
                       for k, m in enumerate(eds)])
    torch.testing.assert_close(bc.GroupedEncoderDecoder(eds).loss(v, y, eps, emulator, 1000.0, 1.0, 10.0), own,
                               rtol=1e-5, atol=1e-5)


def test_emulator_errors_summary_finds_the_output_that_holds_the_relative_error():
    ee = _load("emulator_errors")
    y = np.array([[3.0, 4.0], [300.0, 400.0], [6.0, 8.0]])
    pred = y.copy()
    pred[0, 1] += 0.5  # row 0: |e| 0.5 over |y| 5 = 10%
    pred[1, 0] += 5.0  # row 1: 5 over 500 = 1%
    s = ee.error_summary(y, pred, ["a", "b"])
    assert s["worst_%"] == pytest.approx(10.0) and s["median_%"] == pytest.approx(1.0)
    assert s["p99_%"] == pytest.approx(1.0 + 0.98 * 9.0)  # linear interpolation between 1% and 10%
    assert s["top_output"] == "b" and s["top_share"] == pytest.approx(0.01 / (0.01 + 0.0001))


def test_emulator_errors_appendix_c_ratios_are_the_scorecards_geometric_means():
    from cvsim6 import paper_values

    ee = _load("emulator_errors")
    paper = paper_values.EMULATOR_VALIDATION_STRUCTURAL
    y = np.zeros((2, 16))
    pred = np.stack([3.0 * np.asarray(paper["max"]), np.zeros(16)])  # max error 3x the paper's everywhere
    r = ee.appendix_c_ratios(y, pred)
    assert r["appendix_c_max_x"] == pytest.approx(3.0)
    mean_ratio = 1.5 * np.asarray(paper["max"]) / np.asarray(paper["mean"])  # mean of |e| over the two rows
    assert r["appendix_c_mean_x"] == pytest.approx(np.exp(np.log(mean_ratio).mean()))


def test_mcmc_walkers_splits_the_budget_and_counts_parameters_short_of_the_targets(tmp_path):
    mw = _load("mcmc_walkers")
    assert [mw.steps_for(672000, w) for w in (48, 96, 192)] == [14000, 7000, 3500]  # equal walker-steps
    assert mw.steps_for(1000, 96) == 10
    with pytest.raises(ValueError, match="only 3 steps"):
        mw.steps_for(300, 96)
    diag = {"rhat": np.array([1.01, 1.06, np.inf, 1.05]), "ess_bulk": np.array([900.0, 350.0, 10.0, 500.0]),
            "ess_tail": np.array([420.0, 800.0, 12.0, 399.0])}
    s = mw.summarise(diag, 1.05, 400.0)
    assert s["rhat_max"] == np.inf and s["ess_min"] == 10.0  # min of bulk and tail over the parameters
    assert s["n_rhat_over"] == 2 and s["n_ess_under"] == 3 and not s["converged"]  # R-hat 1.05 meets the target
    assert mw.summarise({k: v[:1] for k, v in diag.items()})["converged"]
    table = pd.DataFrame({"case": ["a", "a", "b", "c"], "walkers": [48, 96, 48, 96],
                          "ess_min_per_cpu_s": [2.0, 3.0, 4.0, 1.0]})
    ratio = mw.add_baseline_ratios(table, 48)["ess_per_cpu_vs_baseline"]
    assert ratio.iloc[:3].tolist() == [1.0, 1.5, 1.0] and np.isnan(ratio.iloc[3])  # c has no baseline row
    pd.DataFrame({"case": ["a", "b"], "rhat_max": [1.2, 1.01], "ess_min": [66.0, 900.0]}).to_csv(tmp_path / "d.csv")
    wf = mw.add_workflow_diagnostics(table, tmp_path / "d.csv", 48)
    assert wf["workflow_ess_min"].iloc[[0, 2]].tolist() == [66.0, 900.0]  # on the baseline rows only
    assert wf["workflow_rhat_max"].iloc[[1, 3]].isna().all()
    assert mw.add_workflow_diagnostics(table, None, 48)["workflow_rhat_max"].isna().all()


def test_restart_basins_reads_candidate_ranges_and_counts_used_latent_dimensions():
    rb = _load("restart_basins")
    assert rb.parse_candidates("0-8") == list(range(9))
    assert rb.parse_candidates("3,5,7") == [3, 5, 7]
    assert rb.parse_candidates("0-2,6,1") == [0, 1, 2, 6]
    # 11 directions at 2.5 nats and 8 unused: none overloaded
    even = np.r_[np.full(11, 2.5), np.full(8, 0.01)]
    assert rb.latent_usage(even) == {"dims_used": 11, "kl_max_over_median": 1.0}
    # 9 in use, one carrying twice the median's work; the threshold is strict
    loaded = np.r_[5.0, np.full(8, 2.5), 0.5, np.zeros(9)]
    assert rb.latent_usage(loaded) == {"dims_used": 9, "kl_max_over_median": 2.0}
    none = rb.latent_usage(np.zeros(19))
    assert none["dims_used"] == 0 and np.isnan(none["kl_max_over_median"])


def test_continuation_epochs_summary_keeps_the_best_tested_epoch_and_counts_cpu_after_the_choice(tmp_path):
    ce = _load("continuation_epochs")
    nan = float("nan")
    pd.DataFrame({"epoch": [1, 2, 3, 4, 5, 6], "test_loss": [9.0, 7.0, nan, 5.0, nan, 6.0],
                  "cpu_seconds": [1.0, 1.0, 2.0, 2.0, 3.0, 3.0]}).to_csv(tmp_path / "losses.csv", index=False)
    # the kept weights: the lowest tested loss (epoch 4); CPU of the epochs after the choice (2) only
    assert ce.training_summary(tmp_path / "losses.csv", 2) == {"best_epoch": 4, "best_test_loss": 5.0,
                                                                "continuation_cpu_s": 10.0}
    # the scorecard's every headline file: the evaluations' under a folder of their own, the rest the run's
    from cvsim6.reporting import scorecard

    files = ce.headline_files(Path("run"), Path("work"))
    assert set(files) == set(scorecard.HEADLINE_FILES)
    assert {k for k, f in files.items() if f.startswith("work")} == set(ce.EVALUATED)
    assert files["svd"] == "work/structural/manifold_svd.json"
    assert files["stiffness"] == "run/results/stiffness/sr_extremes.csv"
    assert all(f.startswith("run/results/") for f in ce.headline_files(Path("run")).values())


def test_ehr_network_swap_ratio_counts_only_outputs_seen_in_more_than_ten_patients():
    from cvsim6 import paper_values
    from cvsim6.registry import OUTPUT_NAMES

    sw = _load("ehr_network_swap")
    i = list(paper_values.EHR_DELTAS).index(0.5)
    given = [n for n in OUTPUT_NAMES if paper_values.EHR_EK[n][i] is not None]
    counted, few = given[:-1], given[-1]  # the last given output seen in 10 patients only
    factors = {n: (2.0 if j % 2 else 0.5) for j, n in enumerate(counted)}
    factors[counted[0]] = 8.0  # the geometric mean is 8^(1/m) times 2^a 0.5^b
    rows = {n: (factors[n] * paper_values.EHR_EK[n][i], 40) for n in counted}
    rows[few] = (100.0 * paper_values.EHR_EK[few][i], 10)
    rows.update({n: (123.0, 40) for n in OUTPUT_NAMES if n not in given})  # no paper value: left out
    e_k = pd.DataFrame.from_dict(rows, orient="index", columns=["e_k", "count"])
    ratio, each = sw.ek_ratio(e_k, 0.5)
    assert list(each) == [n for n in OUTPUT_NAMES if n in counted]
    assert each[counted[0]] == pytest.approx(8.0)
    assert ratio == pytest.approx(float(np.exp(np.mean(np.log(list(factors.values()))))))
    e_k["e_k"] *= 3.0
    assert sw.ek_ratio(e_k, 0.5)[0] == pytest.approx(3.0 * ratio)


def test_algorithm1_inverts_with_the_workflow_configs_settings():
    """The benchmark's inversion settings are the config's ehr_study ones, named as the
    inversion function takes them (no second copy of the workflow's values)."""
    import inspect

    import yaml

    from cvsim6.studies.ehr import invert_observations

    a1 = _load("algorithm1")
    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    cfg["ehr_study"]["n_latent"] = 37  # a value of this config, not a default of the script
    settings = a1.inversion_settings(cfg)
    assert settings["n_latent"] == 37 and settings["seed"] == cfg["seed"]
    assert settings["corrector_steps"] == cfg["ehr_study"]["corrector_steps"]
    assert a1.inversion_settings(cfg, seed=7)["seed"] == 7
    assert set(settings) <= set(inspect.signature(invert_observations).parameters)


def test_training_benchmark_reports_a_diverged_schedules_epoch_and_its_best_before():
    tb = _load("training")
    df = pd.DataFrame({"schedule": ["ours"] * 3 + ["cap"] * 4, "epoch": [1, 2, 3, 1, 2, 3, 4],
                       "test_decoder": [0.5, 0.4, float("nan"), 0.5, 0.3, 0.2, 0.25],
                       "cpu_seconds_total": [1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 4.0],
                       "diverged_at_epoch": [3] * 3 + [0] * 4})
    table = tb.reached(df, "test_decoder", [0.5, 1.0], 4.0).set_index("schedule")
    assert table.loc["ours", "diverged at epoch"] == 3 and table.loc["cap", "diverged at epoch"] == 0
    # the best finite error within each fraction of the 4 CPU-s budget
    assert table.loc["ours", "0.5 x budget"] == 0.4 and table.loc["ours", "1 x budget"] == 0.4
    assert table.loc["cap", "0.5 x budget"] == 0.3 and table.loc["cap", "1 x budget"] == 0.2
    # a schedule that diverged in its first epoch has no finite error, and is still reported
    first = tb.reached(df.assign(schedule="first", test_decoder=float("nan"), diverged_at_epoch=1).head(1),
                       "test_decoder", [1.0], 4.0).iloc[0]
    assert first["diverged at epoch"] == 1 and first["epochs"] == 0 and np.isnan(first["1 x budget"])


def test_simulator_accuracy_errors_in_noise_units_and_the_fastest_batch_at_equal_accuracy():
    sa = _load("simulator_accuracy")
    truth = np.tile(np.linspace(1.0, 16.0, 16), (3, 1))
    y = truth.copy()
    y[1, 4] += 2.5 * registry.noise_std()[4]  # one entry off by 2.5 noise standard deviations
    y[2, 0] += 0.5 * registry.noise_std()[0]
    err = sa.errors(y, truth)
    assert err["max_error_noise_sd"] == pytest.approx(2.5)
    sd = registry.noise_std()
    assert err["max_rel_error"] == pytest.approx(max(2.5 * sd[4] / 5.0, 0.5 * sd[0] / 1.0))
    assert err["median_set_error_noise_sd"] == pytest.approx(0.5)  # per set: 0, 2.5, 0.5
    points = pd.DataFrame({
        "path": ["reference", "batch", "batch", "batch", "reference", "reference"],
        "setting": ["truth", "b100", "b300", "b600", "r1e-4", "r1e-6"],
        "sets_per_cpu_s": [0.1, 4000.0, 2500.0, 1500.0, 0.5, 0.25],
        "max_error_noise_sd": [np.nan, 3e-2, 4e-3, 1e-3, 5e-3, 1e-5]})
    eq = sa.equal_accuracy(points).set_index("reference")
    assert list(eq.index) == ["r1e-4", "r1e-6"]  # the truth has no error of its own
    # b300 and b600 are as accurate as r1e-4; b300 is the faster of them
    assert eq.loc["r1e-4", "batch"] == "b300" and eq.loc["r1e-4", "speed_at_equal_accuracy"] == pytest.approx(5000)
    assert eq.loc["r1e-6", "batch"] == "none" and np.isnan(eq.loc["r1e-6", "speed_at_equal_accuracy"])
    # no set to compare, an output of exactly 0, no Radau setting: no error raised
    assert all(np.isnan(v) for v in sa.errors(y[:0], truth[:0]).values())
    zero = truth.copy()
    zero[:, 4] = 0.0
    assert sa.errors(zero, zero)["max_rel_error"] == 0.0
    assert sa.equal_accuracy(points[points["path"] == "batch"]).empty
