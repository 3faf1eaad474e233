"""The workflow's target ``references``: its jobs in dry runs, and kept out of ``all``. Its real run
on the smoke networks is in test_workflow_smoke.py, in the tree that trained them."""
from __future__ import annotations

import pytest
import yaml

from conftest import REFERENCE_RULES, ROOT, planned_rules, snakemake


@pytest.mark.parametrize("configfile", [None, "config/smoke.yaml", "config/published.yaml"])
def test_dry_run_lists_the_reference_jobs(configfile):
    args = ["-n", "--forceall", "references"] + (["--configfile", configfile] if configfile else [])
    proc = snakemake(*args)
    assert proc.returncode == 0, proc.stderr
    jobs = planned_rules(proc.stdout + proc.stderr)
    name = "config/smoke.yaml" if configfile == "config/smoke.yaml" else "config/config.yaml"
    cfg = yaml.safe_load((ROOT / name).read_text())["references"]
    n_cases = cfg["mcmc"]["n_simulated"] + cfg["mcmc"]["n_patients"]
    assert jobs["reference_mcmc"] == n_cases
    assert jobs["sobol_prior"] == 2 and jobs["sobol_heatmap"] == 2
    assert jobs["reference_marginals"] == len(cfg["figure_cases"])
    for rule in REFERENCE_RULES - {"reference_mcmc", "sobol_prior", "sobol_heatmap", "reference_marginals"}:
        assert jobs[rule] == 1, rule


def test_references_are_not_part_of_all():
    proc = snakemake("-n", "--forceall", "all")
    assert proc.returncode == 0, proc.stderr
    jobs = planned_rules(proc.stdout + proc.stderr)
    assert not {"sobol_prior", "reference_mcmc", "references"} & set(jobs)
