"""The smoke workflow end to end, run once for all the stages' checks: Snakemake, in a copy of
the workflow, runs target ``all`` with the paper's published networks (no training), then
``all`` and ``calibration`` with this workflow's own networks in the same results/ tree. The
checks of each stage (training, structural study, EHR study, calibration) and of the two network
sources side by side in one scorecard read that one tree: one run of the smoke workflow instead
of one per stage (the test suite's time on 2 cores)."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import (LOCAL_EHR_CSV, LOCAL_PUBLISHED, copy_workflow, needs_local_ehr, needs_published,
                      REFERENCE_RULES, planned_rules, require_local, snakemake)
from cvsim6.data import datasets
from cvsim6.studies import ehr_methods
from cvsim6.studies import ehr as ehr_study
from cvsim6 import nets as networks
from cvsim6 import paper_values
from cvsim6.data import priors
from cvsim6 import registry
from cvsim6.model import solver
from cvsim6.model.equations import outside_domain
from cvsim6.reporting.headline_files import headline_files

SMOKE = ["--configfile", "config/smoke.yaml", "local.yaml"]
#: Without the local EHR data (which target ``all`` needs) the training and structural stages run alone.
STAGE_TARGETS = ["results/tables/structural_emulator_validation.md", "results/tables/ehr_architectures.md",
                 "results/tables/structural_schedules.md", "results/models/ehr/encoder_decoder_delta0.5.pt",
                 "results/models/ehr/flow_delta2.pt", "results/training/ehr/emulator_l2_errors.json",
                 "results/training/structural/flow_delta0_marginals.png",
                 "results/training/ehr/encoder_decoder_delta0.5_losses.png",
                 "results/training/structural/encoder_decoder_delta0_losses.png",
                 "results/tables/structural_inversion_errors.md", "results/structural/manifold_trajectories.png",
                 "results/structural/manifold_parallel_coordinates.png", "results/structural/manifold_svd.png",
                 "results/structural/missing_data_trajectories.png", "results/structural/jacobian_spectra.png"]

pytestmark = pytest.mark.slow


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A copy of the workflow, with the local copies of the data in ``local.yaml``."""
    work = copy_workflow(tmp_path_factory.mktemp("smoke"))
    local = {}
    if LOCAL_EHR_CSV.is_file():
        local["ehr_data"] = {"path": str(LOCAL_EHR_CSV)}
    if LOCAL_PUBLISHED.is_dir():
        local["networks"] = {"published": {"path": str(LOCAL_PUBLISHED)}}
    (work / "local.yaml").write_text(yaml.safe_dump(local))
    return work


@pytest.fixture(scope="module")
def published_run(work) -> dict:
    """Target ``all`` with the published networks; what the tree held right after it."""
    require_local("published", "ehr")
    proc = snakemake("--cores", "2", "all", *SMOKE, "config/published.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    pub = work / "results" / "published"
    return {"trained_models": (work / "results/models").exists(),
            "train_logs": sorted(p.name for p in (work / "logs").glob("train_*")),
            "card": pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline"),
            "table5_digest": digest(pub / "tables/ehr_error_per_output.csv")}


@pytest.fixture(scope="module")
def trained_run(work, request) -> Path:
    """This workflow's own networks, after the published run when there is one (one tree)."""
    if LOCAL_PUBLISHED.is_dir() and LOCAL_EHR_CSV.is_file():
        request.getfixturevalue("published_run")
    targets = ["all", "calibration"] if LOCAL_EHR_CSV.is_file() else STAGE_TARGETS
    proc = snakemake("--cores", "2", *targets, *SMOKE, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return work


@needs_published
@needs_local_ehr
def test_published_networks_run_without_training(work, published_run):
    pub = work / "results" / "published"
    # the converted networks: the paper's architecture, float64, with their origin recorded
    flow, info = networks.load_model(pub / "models/ehr/flow_delta0.5.pt", with_info=True)
    assert info["source"] == "published" and info["noise_level"] == 0.5
    assert networks.count_parameters(flow) == paper_values.PARAMETER_COUNTS["ehr"]["NN_f"]
    assert not published_run["trained_models"]  # nothing was trained
    assert not published_run["train_logs"]
    for rel in ("tables/ehr_error_per_output.md", "tables/structural_inversion_errors.md",
                "structural/manifold_svd.png", "ehr/patient_predictions_delta0.5.png",
                "training/ehr/emulator_l2_errors.png", "tables/structural_emulator_validation.md"):
        assert (pub / rel).is_file(), rel
    card = published_run["card"]
    assert "published / paper" in card.columns and "trained" not in card.columns
    lam = card[card.index.str.startswith("Stiffness")]
    assert len(lam) == 8
    # the published emulator on our (smoke) validation sets: the paper's appendix C accuracy
    emulator_row = card.loc[card.index.str.startswith("Structural emulator, mean")].iloc[0]
    assert 0.5 < emulator_row["published / paper"] < 2.0


@needs_published
@needs_local_ehr
def test_published_and_trained_results_sit_side_by_side(published_run, trained_run):
    work = trained_run
    assert (work / "results/models/ehr/flow_delta0.5.pt").is_file()
    assert digest(work / "results/published/tables/ehr_error_per_output.csv") == published_run["table5_digest"]
    card = pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline")
    assert {"trained", "trained / paper", "published", "published / paper"} <= set(card.columns)
    # the stiffness rows do not depend on the networks: one value for both sources
    lam = card[card.index.str.startswith("Stiffness")]
    pd.testing.assert_series_equal(lam["trained"], lam["published"], check_names=False)
    md = (work / "results/report/reproduction.md").read_text()
    assert "**trained**" in md and "**published**" in md


def test_training_stage_end_to_end(trained_run):
    work = trained_run
    targets = ["results/tables/structural_emulator_validation.md",
               "results/tables/ehr_architectures.md",
               "results/tables/structural_schedules.md",
               "results/models/ehr/encoder_decoder_delta0.5.pt",
               "results/models/ehr/flow_delta2.pt",
               "results/training/ehr/emulator_l2_errors.json",
               "results/training/structural/flow_delta0_marginals.png",
               "results/training/ehr/encoder_decoder_delta0.5_losses.png",
               "results/training/structural/encoder_decoder_delta0_losses.png"]
    # models load, with the architecture of the config and the noise level of the file name
    ed, info = networks.load_model(work / "results/models/ehr/encoder_decoder_delta0.5.pt", with_info=True)
    assert info["noise_level"] == 0.5 and info["stage"] == "encoder_decoder"
    # log_parameters in the smoke config: every parameter but P_th decoded as a logarithm
    assert isinstance(ed.x_scaler, networks.LogStandardizer)
    assert ed.config["log_params"] == [j for j in range(registry.N_PARAMETERS) if registry.PARAMETER_NAMES[j] != "P_th"]
    flow, info = networks.load_model(work / "results/models/ehr/flow_delta2.pt", with_info=True)
    assert info["noise_level"] == 2.0 and networks.count_parameters(flow) == 20280
    # per-epoch losses of every stage, as many rows as configured epochs
    losses = pd.read_csv(work / "results/training/ehr/encoder_decoder_delta0.5_losses.csv")
    assert list(losses["epoch"]) == [1, 2]
    assert losses[["train_loss", "test_loss"]].notna().all().all()
    assert (work / "results/training/ehr/encoder_decoder_delta0.5_losses.png").is_file()
    # the structural encoder/decoder (restarts: 2, restart_target: 1e-3, max_restarts: 3 in the smoke
    # config): each of the two candidates trained in a job of its own (log, benchmark); after one
    # epoch neither reconstructs every parameter, so the run screened a third itself, and chose by
    # the three test losses at the choice
    _, info = networks.load_model(work / "results/models/structural/encoder_decoder_delta0.pt", with_info=True)
    restart = info["restart"]
    assert restart["target"] == 1e-3 and len(restart["worst_reconstruction"]) == 3
    assert all(w > 1e-3 for w in restart["worst_reconstruction"])
    cands = [pd.read_csv(work / f"results/models/structural/encoder_decoder_delta0.pt.ckpt.candidate{c}.csv")
             for c in range(3)]
    assert restart["test_loss"] == [float(df.loc[df["epoch"] == restart["epochs"], "test_loss"].iloc[0])
                                    for df in cands]
    assert restart["chosen"] == min(range(3), key=lambda c: (restart["test_loss"][c], c))
    for c in range(2):
        assert "done" in (work / f"logs/train_encoder_decoder_candidate/structural_delta0_{c}.log").read_text()
        assert (work / f"logs/benchmarks/train_encoder_decoder_candidate/structural_delta0_{c}.tsv").is_file()
    assert not (work / "logs/train_encoder_decoder_candidate/structural_delta0_2.log").exists()
    # the generated appendix tables state what was run
    arch = pd.read_csv(work / "results/tables/ehr_architectures.csv")
    arch = arch.set_index("Module")
    # the paper's networks, but the EHR emulator's linear skip (23 x 16 weights + 16 biases)
    extra = {"NN_e": registry.N_PARAMETERS * registry.N_OUTPUTS + registry.N_OUTPUTS}
    assert all(arch.loc[m, "Parameters"] == arch.loc[m, "Parameters (paper)"] + extra.get(m, 0) for m in arch.index)
    assert arch.loc["NN_e", "Activation"] == "SiLU + linear skip"
    assert arch.loc["NN_e", "Inputs"] == "logs of the positive parameters, standardized"
    assert arch.loc["NN_v", "Inputs"] == "logs of the positive parameters, standardized"
    assert arch.loc["NN_d", "Inputs"].endswith("(gives the logs of the positive parameters)")
    l2 = json.loads((work / "results/training/ehr/emulator_l2_errors.json").read_text())
    assert l2["n"] == 40 and 0 < l2["mean"] <= l2["max"]
    assert (work / "results/training/structural/flow_delta0_marginals.pdf").is_file()
    # the smoke config floors the structural emulator's output variances (not the EHR one's): the
    # losses then carry the plain MSE beside the weighted loss, and the schedule table says so
    emu = pd.read_csv(work / "results/training/structural/emulator_losses.csv")
    assert {"train_mse", "test_mse"} <= set(emu.columns) and emu["train_mse"].notna().all()
    assert "train_mse" not in pd.read_csv(work / "results/training/ehr/emulator_losses.csv").columns
    sched = pd.read_csv(work / "results/tables/structural_schedules.csv").set_index("Module")
    assert "output variances floored at 0.01" in sched.loc["NN_e", "Schedule"]
    assert "floored" not in sched.loc["NN_f", "Schedule"]
    assert "KL weight ramped up over the first 1 epoch" in sched.loc["NN_v + NN_d", "Schedule"]
    assert "re-evaluation also at prior draws w ~ N(0, I), weight 10" in sched.loc["NN_v + NN_d", "Schedule"]
    # the smoke config's structural encoder/decoder weights the prior-draw re-evaluation (the EHR ones do not)
    ed = pd.read_csv(work / "results/training/structural/encoder_decoder_delta0_losses.csv")
    assert ed["test_prior_reeval"].notna().any() and (ed["test_prior_reeval"].dropna() > 0).all()
    assert "test_prior_reeval" not in pd.read_csv(work / "results/training/ehr/encoder_decoder_delta0.5_losses.csv")
    val = pd.read_csv(work / "results/tables/structural_emulator_validation.csv")
    assert len(val) == 16 and (val["Mean (ours)"] > 0).all() and "Mean (paper)" in val
    # the loss figures are drawn by a rule of their own: a change of the plotting code redraws
    # them and retrains nothing
    code = work / "src/cvsim6/reporting/loss_figures.py"
    text, stat = code.read_text(), code.stat()
    try:
        with open(code, "a") as fh:
            fh.write("\n# changed\n")
        proc = snakemake("-n", *targets, *SMOKE, cwd=work)
    finally:  # the shared tree stays up to date for the other tests
        code.write_text(text)
        os.utime(code, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Updated input files: src/cvsim6/reporting/loss_figures.py" in out
    assert "plot_training_losses" in out and "train_encoder_decoder" not in out and "train_emulator" not in out


def test_structural_stage_end_to_end(trained_run):
    work = trained_run
    targets = ["results/tables/structural_inversion_errors.md", "results/structural/manifold_trajectories.png",
               "results/structural/manifold_parallel_coordinates.png", "results/structural/manifold_svd.png",
               "results/structural/missing_data_trajectories.png", "results/structural/jacobian_spectra.png"]
    t = pd.read_csv(work / "results/tables/structural_inversion_errors.csv")
    assert len(t) == 16 and (t["Max (ours)"] >= t["Mean (ours)"]).all() and "Mean (paper)" in t
    obs = pd.read_csv(work / "results/tables/structural_observation.csv")
    np.testing.assert_allclose(obs["y*"], paper_values.Y_STAR)
    svd = json.loads((work / "results/structural/manifold_svd.json").read_text())
    sv = pd.read_csv(work / "results/structural/manifold_svd.csv")["singular_value"]
    # standardized columns: the squared singular values add up to n_samples per varying column
    v = datasets.read_dataset(work / "results/structural/manifold_samples.parquet")[list(registry.PARAMETER_NAMES)]
    v = v.to_numpy()[~outside_domain(v.to_numpy())]
    assert len(v) == svd["n_samples"]
    assert (sv**2).sum() == pytest.approx(len(v) * (v.std(axis=0) > 0).sum(), rel=1e-6)
    assert svd["n_samples"] + svd["outside_domain"] == 200
    # the reconstruction's spread (smoke config: all 200 draws simulated, sets of the first 100's size)
    rec = json.loads((work / "results/tables/structural_manifold_reconstruction.json").read_text())
    spread = rec["max_rel_l2_error_resampled"]
    assert spread["n_simulated"] == 200 and spread["subset"] == rec["n"] == 100
    assert spread["median_rel_l2_error"] <= spread["q10"] <= spread["q50"] <= spread["q90"]
    miss = pd.read_csv(work / "results/tables/structural_missing_data.csv")
    assert len(miss) == 4 and (np.diff(miss["log_density"]) <= 0).all()
    for name in registry.OUTPUT_NAMES:  # observed entries of y* are kept in every completion
        if name not in paper_values.MISSING_OUTPUTS:
            assert (miss[name] == obs.set_index("Output").loc[name, "y*"]).all()
    jac = json.loads((work / "results/tables/structural_local_identifiability.json").read_text())
    # V0_a, V0_v, V0_r, V0_pa, V0_pv set the outputs only through their sum: 4 exact null
    # directions at every point, in which V0_a holds at least 1 - w_a^2 / sum w^2 = 0.93
    shares = pd.read_csv(work / "results/tables/structural_local_identifiability.csv").set_index("Parameter")
    assert shares.loc["V0_a", "null-space share (mean)"] * jac["local_manifold_dimension"] > 0.9
    assert shares.loc["Hr", "null-space share (max)"] < 1e-6  # observed directly
    for fig in targets[1:]:
        assert (work / fig).with_suffix(".pdf").is_file()


@needs_local_ehr
def test_scorecard_shows_the_reconstruction_spread(trained_run):
    work = trained_run
    rec = json.loads((work / "results/tables/structural_manifold_reconstruction.json").read_text())
    card = pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline")
    row = card.loc[card.index.str.contains("median over 2,000 random sets of 100 of 200 draws")]
    assert len(row) == 1 and row["trained"].iloc[0] == pytest.approx(100 * rec["max_rel_l2_error_resampled"]["q50"])


@needs_local_ehr
def test_ehr_stage_end_to_end(trained_run):
    work = trained_run
    table = pd.read_csv(work / "results/tables/ehr_error_per_output.csv").set_index("Output")
    assert list(table["Counts"]) == [f"{c}/46" for c in (46, 46, 46, 44, 11, 46, 46, 44, 46, 3, 0, 3, 45, 46, 46, 46)]
    assert {"delta=0.5", "delta=2", "paper delta=0.5"} <= set(table.columns)
    assert np.isnan(table.loc["V_l_sys", "delta=0.5"])
    pred = pd.read_parquet(work / "results/ehr/predictions_delta0.5.parquet")
    assert pred["id"].nunique() == 46 and len(pred) == 46 * 100
    # observed entries of each patient are kept in the completion Algorithm 1 returns
    obs = pd.read_csv(work / "results/ehr/patients.csv", index_col="patient")
    first = pred.groupby("id").first()
    for n in registry.OUTPUT_NAMES:
        seen = obs[n].notna()
        np.testing.assert_allclose(first.loc[obs.index[seen], "completed_" + n], obs.loc[seen, n])
    ood = pd.read_csv(work / "results/tables/ehr_ood_delta0.5.csv")
    assert len(ood) == 46 and ood["ood_percentile"].between(0, 100).all()



@needs_local_ehr
def test_calibration_stage_end_to_end(trained_run):
    """Calibration tables of both methods, and the EHR patients' e_k three ways: the emulated
    way equals table 5, the simulated ways are the simulator's outputs of the stored sets."""
    work = trained_run
    cal = pd.read_csv(work / "results/tables/calibration_summary.csv")
    assert len(cal) == 2 * 2 * 23  # methods x noise levels x parameters
    assert set(cal["method"]) == {"inVAErt", "NPE"} and set(cal["noise_level"]) == {0.5, 2.0}
    assert cal["sbc_pvalue"].between(0, 1).all() and (cal["coverage_error"] >= 0).all()
    assert (cal["n_cases"] == 20).all() and (cal["n_samples"] == 20).all()
    for name in ("coverage.png", "rank_ecdf_delta0.5.png", "recovery_delta0.5.png"):
        assert (work / "results/calibration" / name).is_file()
    samples = np.load(work / "results/calibration/samples_delta2.npz")
    assert samples["inVAErt"].shape == samples["NPE"].shape == (20, 20, 23)
    # NPE samples stay in the prior box of the EHR study
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS["ehr"])
    assert (samples["NPE"] >= lo).all() and (samples["NPE"] <= hi).all()

    methods = pd.read_csv(work / "results/tables/ehr_error_methods.csv").set_index("Output")
    table5 = pd.read_csv(work / "results/tables/ehr_error_per_output.csv").set_index("Output")
    for d in ("0.5", "2"):
        np.testing.assert_allclose(methods[f"inVAErt via emulator, delta={d}"], table5[f"delta={d}"])
        for way in ehr_methods.WAYS[1:]:
            ek = methods[f"{way}, delta={d}"]
            seen = table5["Counts"].str.split("/").str[0].astype(int) > 0
            assert ek[seen].notna().sum() >= 1 and ek[~seen].isna().all()
    assert "paper delta=0.5" in methods and "Lowest at delta=0.5" in methods
    # the simulated outputs are the simulator's, of the parameter sets stored beside them
    for f in ("ehr/predictions_delta0.5_simulated.parquet", "ehr/npe_predictions_delta0.5.parquet"):
        pred = pd.read_parquet(work / "results" / f)
        rows = pred[pred["sim_status"] == 0].head(5)
        y, st = solver.simulate_batch(rows[list(registry.PARAMETER_NAMES)].to_numpy(), steps_per_cycle=200)
        np.testing.assert_allclose(rows[[ehr_study.PRED + n for n in registry.OUTPUT_NAMES]].to_numpy(), y)
    npe_pred = pd.read_parquet(work / "results/ehr/npe_predictions_delta0.5.parquet")
    inv = pd.read_parquet(work / "results/ehr/predictions_delta0.5.parquet")
    ok = inv[inv["status"] == "ok"]
    assert npe_pred.loc[npe_pred["status"] == "ok", "id"].nunique() == ok["id"].nunique()
    # NPE inverts the same completed outputs as inVAErt
    a = npe_pred[npe_pred["status"] == "ok"].groupby("id").first()
    b = ok.groupby("id").first()
    cols = ["completed_" + n for n in registry.OUTPUT_NAMES]
    np.testing.assert_array_equal(a.loc[b.index, cols].to_numpy(), b[cols].to_numpy())


@needs_local_ehr
@pytest.mark.parametrize("module", ["structural_figures", "ehr_figures", "calibration_figures",
                                    "stiffness_figures"])
def test_editing_a_figure_module_replans_its_figures_only(trained_run, module):
    """After the whole study ran, an edit of one figure module plans the rules that draw with it
    and nothing else: no simulation, no training, no table."""
    from test_workflow import rule_functions

    work = trained_run
    targets = ["all", "calibration"]
    fresh = snakemake("-n", *targets, *SMOKE, cwd=work)
    assert fresh.returncode == 0 and planned_rules(fresh.stdout + fresh.stderr) == {}, fresh.stdout[-2000:]
    drawing = {rule for rule, function in rule_functions().items()
               if function.startswith(f"cvsim6.reporting.{module}:")}
    assert drawing, module
    code = work / "src/cvsim6/reporting" / f"{module}.py"
    text, stat = code.read_text(), code.stat()
    try:
        code.write_text(text.replace('"""', '"""Edited. ', 1))  # an edit of the module's text only
        proc = snakemake("-n", *targets, *SMOKE, cwd=work)
    finally:  # the shared tree stays up to date for the other tests
        code.write_text(text)
        os.utime(code, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    planned = planned_rules(proc.stdout + proc.stderr)
    assert proc.returncode == 0 and planned, proc.stderr[-2000:]
    planned.pop("all", None)
    planned.pop("calibration", None)
    assert planned and set(planned) <= drawing, sorted(set(planned) - drawing)


@needs_local_ehr
def test_seeds_target_trains_each_seed_on_the_shared_data(trained_run):
    """Target ``seeds`` (smoke config: seeds 0, the default, and 1): seed 1's networks train into
    results/seeds/1/ on the data of ``all``, which stays as it was; the spread's values per seed are
    the scorecard's of each seed's files; afterwards ``all`` reruns only the scorecard, which then
    shows the spread beside the default seed's ratio."""
    from cvsim6.reporting import scorecard as sc

    work = trained_run
    data = {p: digest(p) for p in sorted((work / "results/data").rglob("*.parquet"))}
    default_model = work / "results/models/ehr/encoder_decoder_delta0.5.pt"
    before = digest(default_model)
    proc = snakemake("--cores", "2", "seeds", *SMOKE, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    seed1 = work / "results/seeds/1"
    # the data and the default seed's networks are shared, not redone
    assert {p: digest(p) for p in data} == data and digest(default_model) == before
    assert not (seed1 / "data").exists() and not list((work / "results/seeds").glob("0"))
    # seed 1's networks: trained with seed 1, other weights than seed 0's
    ed1, info = networks.load_model(seed1 / "models/ehr/encoder_decoder_delta0.5.pt", with_info=True)
    ed0 = networks.load_model(default_model)
    assert info["seed"] == 1 and networks.load_model(default_model, with_info=True)[1]["seed"] == 0
    w0, w1 = (dict(m.state_dict()) for m in (ed0, ed1))
    assert w0.keys() == w1.keys() and any(not np.array_equal(w0[k], w1[k]) for k in w0)
    assert (work / "logs/seeds/1/train_emulator/ehr.log").is_file()
    # per seed, the values of the scorecard of that seed's files
    roots = {0: work / "results", 1: seed1}
    table = pd.read_csv(work / "results/report/seeds.csv").set_index("key")
    for seed, root in roots.items():
        files = headline_files(str(work / "results"), str(root))
        values, _ = sc.headline_values(files)
        for key in table.index:
            assert table.loc[key, f"seed {seed}"] == pytest.approx(values[key], rel=1e-12, nan_ok=True), key
    pair = table[["seed 0", "seed 1"]].to_numpy(float)
    np.testing.assert_allclose(table["min"], np.nanmin(pair, axis=1))
    np.testing.assert_allclose(table["max"], np.nanmax(pair, axis=1))
    # `all` afterwards: only the scorecard reruns, and shows the spread
    dry = snakemake("-n", "all", *SMOKE, cwd=work)
    assert set(planned_rules(dry.stdout + dry.stderr)) <= {"reproduction_scorecard", "all"}, dry.stdout[-2000:]
    proc = snakemake("--cores", "2", "all", *SMOKE, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    card = pd.read_csv(work / "results/report/reproduction.csv").set_index("Headline")
    spread = pd.read_csv(work / "results/report/seeds.csv").set_index("Headline")
    for stat in ("min", "median", "max"):
        pd.testing.assert_series_equal(card.loc[spread.index, f"trained {stat} over seeds / paper"],
                                       spread[f"{stat} / paper"], check_names=False)
    # the published networks' headline files, when present, are inputs of the seeds' scorecard:
    # it shows them, and a change to one of them reruns it
    published = headline_files(str(work / "results"), str(work / "results/published"))
    if all(Path(p).is_file() for p in published.values()):
        assert "published / paper" in spread.columns
        emulator = Path(published["ehr_emulator"])
        text, mtime = emulator.read_text(), emulator.stat().st_mtime_ns
        emulator.write_text(json.dumps({**json.loads(text), "max": 1.01 * json.loads(text)["max"]}))
        dry = snakemake("-n", "seeds", *SMOKE, cwd=work)
        emulator.write_text(text)
        os.utime(emulator, ns=(mtime, mtime))  # the tree as it was, for the tests after this one
        assert set(planned_rules(dry.stdout + dry.stderr)) == {"seed_scorecard", "seeds"}, dry.stdout[-2000:]
    else:
        assert "results are absent" in (work / "results/report/seeds.md").read_text()


@needs_local_ehr
def test_references_run_on_the_smoke_networks(trained_run):
    """Target ``references`` (Sobol indices, MCMC posteriors, their comparison with inVAErt and
    NPE) in the tree of ``all`` and ``calibration``: it reruns none of their jobs."""
    work = trained_run
    dry = snakemake("-n", "references", *SMOKE, cwd=work)
    assert set(planned_rules(dry.stdout + dry.stderr)) == REFERENCE_RULES
    proc = snakemake("--cores", "2", "references", *SMOKE, cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    tables = work / "results" / "tables"
    sobol = pd.read_csv(tables / "sensitivity_sobol.csv")
    assert list(sobol.columns[:7]) == ["prior", "output", "parameter", "S1", "S1_conf", "ST", "ST_conf"]
    assert len(sobol) == 2 * 16 * 23
    hr = sobol[(sobol["output"] == "Hr") & (sobol["parameter"] != "Hr")]
    assert (hr[["S1", "ST"]].abs() < 1e-12).all().all()  # the Hr output is the Hr parameter
    diag = pd.read_csv(tables / "reference_posterior_diagnostics.csv")
    assert list(diag.columns[:6]) == ["case", "kind", "rhat_max", "ess_min", "n_samples", "cpu_seconds"]
    assert list(diag["case"]) == ["sim0", "sim1", "ehr0"]
    assert list(diag["kind"]) == ["simulated", "simulated", "patient"]
    # 60 steps at most, the second half kept, 48 walkers; tiny chains cannot reach the targets
    assert (diag["n_samples"] == 48 * 30).all() and (diag["steps"] == 60).all()
    assert (diag["cpu_seconds"] > 0).all() and not diag["converged"].any()
    assert (diag["not converged"].str.len() > 0).all()
    comp = pd.read_csv(tables / "reference_posteriors.csv")
    assert list(comp.columns[:3]) == ["case", "method", "c2st"]
    assert len(comp) == 3 * 2 and set(comp["method"]) == {"inVAErt", "NPE"}
    assert comp["c2st"].between(0, 1).all()
    # the patient's reference conditions on its observed outputs only
    cases = pd.read_csv(work / "results/references/cases.csv")
    ehr0 = cases.set_index("case").loc["ehr0"]
    observed = int(ehr0[[f"y_{n}" for n in registry.OUTPUT_NAMES]].notna().sum())
    assert int(diag.set_index("case").at["ehr0", "observed_outputs"]) == observed < 16
    assert cases.set_index("case").loc["ehr0", [f"theta_{n}" for n in registry.PARAMETER_NAMES]].isna().all()
    # the simulated cases are the calibration stage's, with its noisy observations
    cal = np.load(work / "results/calibration/samples_delta0.5.npz")
    np.testing.assert_array_equal(cases.loc[:1, [f"y_{n}" for n in registry.OUTPUT_NAMES]].to_numpy(), cal["y_obs"][:2])
    ident = pd.read_csv(tables / "sensitivity_identifiability.csv")
    assert list(ident["Parameter"]) == list(registry.PARAMETER_NAMES) and set(ident["agree"]) <= {"yes", "no"}
    for rel in ("references/sobol_structural.png", "references/sobol_ehr.pdf", "references/marginals_sim0.png",
                "references/marginals_ehr0.png"):
        assert (work / "results" / rel).is_file(), rel
    # bit-reproducible: a forced rerun of one chain gives the same file contents
    before = dict(np.load(work / "results/references/mcmc/sim0.npz"))
    # (targets before --forcerun, which takes several values)
    proc = snakemake("--cores", "1", "results/references/mcmc/sim0.npz", "--forcerun", "reference_mcmc", *SMOKE,
                     cwd=work)
    assert "rule input_parameter_table" not in proc.stdout + proc.stderr
    assert proc.returncode == 0, proc.stderr[-3000:]
    after = dict(np.load(work / "results/references/mcmc/sim0.npz"))
    np.testing.assert_array_equal(before["samples"], after["samples"])
    np.testing.assert_array_equal(before["rhat"], after["rhat"])
