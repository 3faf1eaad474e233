"""The smoke workflow through workflow/profiles/slurm on a real (one-node) SLURM cluster.

A cluster is started on this machine (tests/slurm_cluster.py: Debian's slurm-wlm and
munge, installed with apt-get when missing; controller and node on localhost, no
accounting daemon). The smoke workflow runs once locally and once with the SLURM
profile; every job except the local rules must have gone through sbatch (Snakemake's
log gives the SLURM job ids, slurmctld's log confirms each was submitted, started in
the profile's partition and exited 0), and the deterministic results (tables, parquet
data, model weights) must equal the local run's. Needs root; skips only when not root
or when SLURM is missing and apt-get cannot install it, and fails instead where
``CVSIM6_REQUIRE_LOCAL=1`` (CI) says that a cluster must run.

Each SLURM job costs about 10 s more than the same job run locally (two Snakemake
start-ups per job: the sbatch script and the srun step), so the whole smoke workflow
(about 55 jobs) takes about 8 minutes on 2 cores through SLURM. By default the test
runs one study's chain instead (tables, prior sampling, the three simulation shards,
gather, the three networks, the inversion table: every kind of stage); set
``CVSIM6_SLURM_FULL=1`` to run target ``all``.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest
import torch
import yaml

import slurm_cluster
from conftest import LOCAL_EHR_CSV, REQUIRE_LOCAL, ROOT, copy_workflow, skip_or_fail, snakemake

pytestmark = pytest.mark.slow

PROFILE = ROOT / "workflow" / "profiles" / "slurm"
SUBMITTED = re.compile(r"Job (\d+) has been submitted with SLURM jobid (\d+) \(log: (\S+)\)")
#: How many seconds each stage took, printed at the end (pytest -s or -rA shows them).
TIMINGS: dict[str, float] = {}


#: The default targets: the structural study's chain from prior sampling to its inversion table.
CHAIN_TARGETS = [
    "results/tables/input_parameters.csv",
    "results/models/structural/flow_delta0.pt",
    "results/models/structural/encoder_decoder_delta0.pt",
    "results/tables/structural_inversion_errors.csv",
]


def smoke_args() -> list[str]:
    """Targets and smoke config: CHAIN_TARGETS, or ``all`` with CVSIM6_SLURM_FULL=1 (the EHR
    data from the local copy when there is one, else downloaded; under CVSIM6_REQUIRE_LOCAL=1
    a missing local copy fails)."""
    if os.environ.get("CVSIM6_SLURM_FULL", "") not in ("", "0"):
        args = ["all", "--configfile", "config/smoke.yaml"]
        if LOCAL_EHR_CSV.is_file():
            args += ["--config", f"ehr_data={{'path': '{LOCAL_EHR_CSV}'}}"]
        elif REQUIRE_LOCAL:
            pytest.fail(f"local copy of the EHR data not present: {LOCAL_EHR_CSV} (CVSIM6_REQUIRE_LOCAL is set)",
                        pytrace=False)
        return args
    return [*CHAIN_TARGETS, "--configfile", "config/smoke.yaml"]


def run_snakemake(work: Path, *args: str, timeout: float = 1800) -> subprocess.CompletedProcess:
    """Snakemake in ``work``; its wall time (s) goes to TIMINGS."""
    t0 = time.monotonic()
    proc = snakemake(*args, cwd=work, timeout=timeout)
    TIMINGS[work.name] = time.monotonic() - t0
    return proc


def run_log(work: Path) -> str:
    """Snakemake's log of the (only) run in ``work``."""
    logs = sorted((work / ".snakemake" / "log").glob("*.snakemake.log"))
    assert len(logs) == 1, logs
    return logs[0].read_text()


def jobs_by_rule(log: str, kind: str = "(?:local)?rule") -> Counter:
    """Rule name of every job a Snakemake log announces (``rule X:`` / ``localrule X:``)."""
    return Counter(re.findall(rf"^{kind} (\w+):$", log, flags=re.M))


def profile_partition() -> str:
    cfg = yaml.safe_load((PROFILE / "config.yaml").read_text())
    return str(cfg["default-resources"]["slurm_partition"]).strip("'\"")


def declared_localrules() -> set[str]:
    """Rules named in ``localrules:`` directives of the workflow (run by Snakemake itself)."""
    names: set[str] = set()
    for f in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        # "localrules: a, b" or "localrules:" followed by indented lines "    a,"
        for same_line, indented in re.findall(r"^localrules:([^\n]*)\n((?:[ \t]+[^\n]*\n)*)", f.read_text(),
                                              flags=re.M):
            names.update(re.findall(r"\w+", same_line + indented))
    return names


# ----------------------------------------------------------------------------- comparison
def _equal_payload(a, b, where: str) -> list[str]:
    """Differences between two torch.load payloads: tensors exactly, the rest by ==."""
    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        ok = (isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) and a.dtype == b.dtype
              and a.shape == b.shape and torch.equal(a, b))
        return [] if ok else [f"{where}: tensors differ"]
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return [f"{where}: keys {sorted(a)} != {sorted(b)}"]
        return [d for k in a for d in _equal_payload(a[k], b[k], f"{where}[{k!r}]")]
    return [] if a == b else [f"{where}: {a!r} != {b!r}"]


def compare_results(expected: Path, got: Path) -> tuple[list[str], Counter]:
    """Differences between two ``results/`` trees, and how many files of each kind were compared.

    Same file names everywhere; contents compared where they are deterministic: parquet
    frames and CSV tables exactly (except the per-epoch wall times, column ``seconds``),
    Markdown tables as text, JSON by value, model files (.pt) and the model part of
    training checkpoints (.ckpt) tensor by tensor. Figures (.png, .pdf) are only required
    to exist.
    """
    names_a = {p.relative_to(expected) for p in expected.rglob("*") if p.is_file()}
    names_b = {p.relative_to(got) for p in got.rglob("*") if p.is_file()}
    diffs = [f"only in {expected}: {sorted(map(str, names_a - names_b))}"] if names_a - names_b else []
    if names_b - names_a:
        diffs.append(f"only in {got}: {sorted(map(str, names_b - names_a))}")
    compared: Counter = Counter()
    for name in sorted(names_a & names_b):
        a, b, ext = expected / name, got / name, name.suffix
        try:
            if ext == ".parquet":
                pd.testing.assert_frame_equal(pd.read_parquet(a), pd.read_parquet(b), check_exact=True)
            elif ext == ".csv":
                fa, fb = pd.read_csv(a), pd.read_csv(b)
                pd.testing.assert_frame_equal(fa.drop(columns=["seconds", "cpu_seconds"], errors="ignore"),
                                              fb.drop(columns=["seconds", "cpu_seconds"], errors="ignore"), check_exact=True)
            elif ext in (".md", ".txt", ".tsv"):
                assert a.read_text() == b.read_text(), "text differs"
            elif ext == ".json":
                assert json.loads(a.read_text()) == json.loads(b.read_text()), "JSON differs"
            elif ext == ".pt":
                diffs += _equal_payload(torch.load(a, weights_only=True), torch.load(b, weights_only=True), str(name))
            elif ext == ".ckpt":  # the rest holds wall times
                diffs += _equal_payload(torch.load(a, weights_only=True)["model"],
                                        torch.load(b, weights_only=True)["model"], f"{name}[model]")
            else:
                continue
            compared[ext] += 1
        except AssertionError as exc:
            diffs.append(f"{name}: {str(exc)[:500]}")
    return diffs, compared


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def cluster(request, tmp_path_factory):
    """A running one-node SLURM cluster; its daemons stop when the module's tests end, pass or fail.
    Where none can run here the test skips, or fails under CVSIM6_REQUIRE_LOCAL=1."""
    t0 = time.monotonic()
    try:
        slurm_cluster.ensure_installed()
    except slurm_cluster.Unavailable as exc:
        skip_or_fail(f"no SLURM cluster: {exc}")
    TIMINGS["install check"] = time.monotonic() - t0
    c = slurm_cluster.Cluster(tmp_path_factory.mktemp("slurm_cluster"), partition=profile_partition())
    request.addfinalizer(c.stop)
    t0 = time.monotonic()
    try:
        c.start()
    except slurm_cluster.Unavailable as exc:
        skip_or_fail(f"no SLURM cluster: {exc}")
    TIMINGS["cluster start"] = time.monotonic() - t0
    return c


@pytest.fixture(scope="module")
def local_run(tmp_path_factory) -> Path:
    """The smoke workflow run locally (``--cores 2``), the reference of the SLURM run."""
    work = copy_workflow(tmp_path_factory.mktemp("smoke") / "local")
    proc = run_snakemake(work, "--cores", "2", *smoke_args())
    assert proc.returncode == 0, proc.stderr[-5000:]
    return work


# ----------------------------------------------------------------------------- the test
def test_smoke_workflow_through_slurm_profile(cluster, local_run, tmp_path):
    work = copy_workflow(tmp_path / "slurm")
    # The profile as shipped, plus what a cluster without accounting needs: squeue for the
    # job states (sacct has nothing to read). The first status check after 2 s instead of
    # 40 s only makes this short run faster; the interval grows by itself.
    proc = run_snakemake(work, "--workflow-profile", str(PROFILE.relative_to(ROOT)),
                         "--slurm-status-command", "squeue", "--slurm-init-seconds-before-status-checks", "2",
                         "--slurm-keep-successful-logs", *smoke_args())
    assert proc.returncode == 0, (proc.stderr[-8000:], cluster.logs())

    # Every job except the local rules was submitted with sbatch ...
    log = run_log(work)
    submitted = SUBMITTED.findall(log)
    assert submitted, log[-3000:]
    rule_of_job, slurm_ids = {}, []
    for job, slurm_id, slurm_log in submitted:
        rule_of_job[job] = re.search(r"/rule_(\w+)/", slurm_log).group(1)
        slurm_ids.append(slurm_id)
    ran_here = jobs_by_rule(log, "localrule")
    assert set(ran_here) <= declared_localrules(), ran_here
    reference = jobs_by_rule(run_log(local_run))
    assert Counter(rule_of_job.values()) + ran_here == reference
    assert any(r.startswith("train_") for r in rule_of_job.values())
    # ... and slurmctld saw each submission, started it in the profile's partition, and
    # the last attempt of each job exited 0 (its SLURM log kept, naming the job's rule).
    ctld = cluster.ctld_log.read_text()
    for slurm_id in slurm_ids:
        assert re.search(rf"_slurm_rpc_submit_batch_job: JobId={slurm_id}\b", ctld), slurm_id
        started = (rf"Allocate JobId={slurm_id} .*Partition={cluster.partition}\b"  # main scheduler
                   rf"|Started JobId={slurm_id} in {cluster.partition} ")  # backfill scheduler
        assert re.search(started, ctld), slurm_id
    last_attempt = {job: slurm_id for job, slurm_id, _ in submitted}
    for job, slurm_id in last_attempt.items():
        assert f"_job_complete: JobId={slurm_id} WEXITSTATUS 0" in ctld, (job, slurm_id)
        slurm_log = next(Path(p) for j, i, p in submitted if i == slurm_id)
        assert f"rule {rule_of_job[job]}:" in slurm_log.read_text()

    # Results equal the local run's.
    diffs, compared = compare_results(local_run / "results", work / "results")
    assert not diffs, "\n".join(diffs)
    assert compared[".pt"] >= 3 and compared[".parquet"] >= 5 and compared[".csv"] >= 5, compared
    print(f"\nSLURM jobs: {len(last_attempt)} ({len(slurm_ids)} submissions); compared {dict(compared)}; "
          + ", ".join(f"{k}: {v:.0f} s" for k, v in TIMINGS.items()))
