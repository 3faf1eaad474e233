"""The workflow's target ``references``: its jobs in dry runs, kept out of ``all``, and a tiny real
run of the smoke config (Sobol, MCMC, comparison with this workflow's smoke networks)."""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import LOCAL_EHR_CSV, ROOT, copy_workflow, needs_local_ehr, snakemake
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES


def job_counts(out: str) -> dict[str, int]:
    """``{rule: jobs}`` from the job-stats table of a dry run."""
    return {m[1]: int(m[2]) for m in re.finditer(r"^(\w+)\s+(\d+)$", out, flags=re.M)}


@pytest.mark.parametrize("configfile", [None, "config/smoke.yaml", "config/published.yaml"])
def test_dry_run_lists_the_reference_jobs(configfile):
    args = ["-n", "--forceall", "references"] + (["--configfile", configfile] if configfile else [])
    proc = snakemake(*args)
    assert proc.returncode == 0, proc.stderr
    jobs = job_counts(proc.stdout + proc.stderr)
    name = "config/smoke.yaml" if configfile == "config/smoke.yaml" else "config/config.yaml"
    cfg = yaml.safe_load((ROOT / name).read_text())["references"]
    n_cases = cfg["mcmc"]["n_simulated"] + cfg["mcmc"]["n_patients"]
    assert jobs["reference_mcmc"] == n_cases
    assert jobs["sobol_prior"] == 2 and jobs["sobol_heatmap"] == 2
    assert jobs["reference_marginals"] == len(cfg["figure_cases"])
    for rule in ("sobol_tables", "sensitivity_identifiability", "reference_cases", "reference_diagnostics",
                 "reference_comparison", "references"):
        assert jobs[rule] == 1, rule


def test_references_are_not_part_of_all():
    proc = snakemake("-n", "--forceall", "all")
    assert proc.returncode == 0, proc.stderr
    jobs = job_counts(proc.stdout + proc.stderr)
    assert not {"sobol_prior", "reference_mcmc", "references"} & set(jobs)


@pytest.mark.slow
@needs_local_ehr
def test_smoke_run_of_the_references(tmp_path):
    work = copy_workflow(tmp_path / "work")
    (work / "local.yaml").write_text(yaml.safe_dump({"ehr_data": {"path": str(LOCAL_EHR_CSV)}}))
    proc = snakemake("--cores", "2", "references", "--configfile", "config/smoke.yaml", "local.yaml", cwd=work)
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
    observed = int(ehr0[[f"y_{n}" for n in OUTPUT_NAMES]].notna().sum())
    assert int(diag.set_index("case").at["ehr0", "observed_outputs"]) == observed < 16
    assert cases.set_index("case").loc["ehr0", [f"theta_{n}" for n in PARAMETER_NAMES]].isna().all()
    # the simulated cases are the calibration stage's, with its noisy observations
    cal = np.load(work / "results/calibration/samples_delta0.5.npz")
    np.testing.assert_array_equal(cases.loc[:1, [f"y_{n}" for n in OUTPUT_NAMES]].to_numpy(), cal["y_obs"][:2])
    ident = pd.read_csv(tables / "sensitivity_identifiability.csv")
    assert list(ident["Parameter"]) == list(PARAMETER_NAMES) and set(ident["agree"]) <= {"yes", "no"}
    for rel in ("references/sobol_structural.png", "references/sobol_ehr.pdf", "references/marginals_sim0.png",
                "references/marginals_ehr0.png"):
        assert (work / "results" / rel).is_file(), rel
    # bit-reproducible: a forced rerun of one chain gives the same file contents
    before = dict(np.load(work / "results/references/mcmc/sim0.npz"))
    # (targets before --forcerun, which takes several values)
    proc = snakemake("--cores", "1", "results/references/mcmc/sim0.npz", "--forcerun", "reference_mcmc",
                     "--configfile", "config/smoke.yaml", "local.yaml", cwd=work)
    assert "rule input_parameter_table" not in proc.stdout + proc.stderr
    assert proc.returncode == 0, proc.stderr[-3000:]
    after = dict(np.load(work / "results/references/mcmc/sim0.npz"))
    np.testing.assert_array_equal(before["samples"], after["samples"])
    np.testing.assert_array_equal(before["rhat"], after["rhat"])
