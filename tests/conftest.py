"""Shared test pieces: seeded parameter sets from both priors, the local data copies and their
markers, the Snakemake runner, and small EHR networks whose flow is a known Gaussian.

Local data: the folder ``shared/data`` beside the repository (``$CVSIM6_LOCAL_DATA`` names
another) holds ``EHR_dataset.csv`` and ``paper_networks/``. Tests marked
:data:`needs_local_ehr` or :data:`needs_published` skip where that copy is absent; with
``CVSIM6_REQUIRE_LOCAL=1`` (set by ``.ci/run``) they fail instead, naming the missing path,
and so do the SLURM tests when no cluster can be started (:func:`skip_or_fail`).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cvsim6.data import priors
from cvsim6 import registry

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).parent / "snakemake")

# ----------------------------------------------------------------------------- local data
LOCAL_DATA = Path(os.environ.get("CVSIM6_LOCAL_DATA") or ROOT.parent / "shared" / "data")
LOCAL_EHR_CSV = LOCAL_DATA / "EHR_dataset.csv"
LOCAL_PUBLISHED = LOCAL_DATA / "paper_networks"
#: ``local_data`` marker argument -> (path, what it is).
LOCAL_COPIES = {"ehr": (LOCAL_EHR_CSV, "local copy of the EHR data"),
                "published": (LOCAL_PUBLISHED, "local copy of the published networks")}
#: Set in CI: a missing local copy or an unavailable SLURM cluster fails instead of skipping.
REQUIRE_LOCAL = os.environ.get("CVSIM6_REQUIRE_LOCAL", "") not in ("", "0")

needs_local_ehr = pytest.mark.local_data("ehr")
needs_published = pytest.mark.local_data("published")


def skip_or_fail(reason: str) -> None:
    """Skip with ``reason``; fail with it when ``CVSIM6_REQUIRE_LOCAL`` is set."""
    if REQUIRE_LOCAL:
        pytest.fail(f"{reason} (CVSIM6_REQUIRE_LOCAL is set: this test must run here)", pytrace=False)
    pytest.skip(reason)


def require_local(*kinds: str) -> None:
    """Skip (or, under ``CVSIM6_REQUIRE_LOCAL``, fail) unless every local copy ``kinds`` exists."""
    missing = [f"{what} not present: {path}" for path, what in (LOCAL_COPIES[k] for k in kinds)
               if not path.exists()]
    if missing:
        skip_or_fail("; ".join(missing))


def pytest_configure(config):
    config.addinivalue_line("markers", "local_data(*kinds): needs the local copies 'ehr' and/or 'published' "
                                       "(skips without them; fails under CVSIM6_REQUIRE_LOCAL=1)")


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Before any fixture: the local copies the test's ``local_data`` markers name."""
    kinds = [k for mark in item.iter_markers("local_data") for k in mark.args]
    if kinds:
        require_local(*dict.fromkeys(kinds))


# ----------------------------------------------------------------------------- Snakemake
def snakemake(*args: str, cwd: Path = ROOT, env: dict | None = None,
              timeout: float = 900) -> subprocess.CompletedProcess:
    """Run Snakemake in ``cwd``, output captured, stdin closed. The timeout (s) guards against a
    hang, not a slow machine: the smoke workflow with the published networks took over 300 s on
    a 2-core machine beside another test file."""
    return subprocess.run([SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env=env, stdin=subprocess.DEVNULL)


#: The rules of target ``references`` beyond those of ``all`` and ``calibration``.
REFERENCE_RULES = {"sobol_prior", "sobol_heatmap", "sobol_tables", "sensitivity_identifiability", "reference_cases",
                   "reference_mcmc", "reference_diagnostics", "reference_comparison", "reference_marginals",
                   "references"}


def planned_rules(dry_run_output: str) -> dict[str, int]:
    """Rule -> job count from the ``Job stats`` table of a Snakemake dry run."""
    planned, inside = {}, False
    for line in dry_run_output.splitlines():
        parts = line.split()
        if line.startswith("Job stats:"):
            inside = True
        elif inside and len(parts) == 2 and parts[1].isdigit() and parts[0] != "total":
            planned[parts[0]] = int(parts[1])
        elif inside and parts and parts[0] == "total":
            break
    return planned


def copy_workflow(dest: Path) -> Path:
    """A copy of what the workflow needs (no results, no .snakemake) under ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")
    shutil.copy2(ROOT / "Snakefile", dest / "Snakefile")
    for folder in ("config", "workflow", "src"):
        shutil.copytree(ROOT / folder, dest / folder, ignore=ignore)
    return dest


# ----------------------------------------------------------------------------- parameter sets
@pytest.fixture(scope="session")
def default_params() -> np.ndarray:
    return registry.default_parameters()


def prior_sample(study: str, n: int, seed: int) -> np.ndarray:
    """``n`` parameter sets (n, 23) drawn uniformly from the paper's prior of ``study``, registry units."""
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS[study])
    return priors.sample_uniform(lo, hi, n, np.random.default_rng(seed))


@pytest.fixture(scope="session")
def structural_sets() -> np.ndarray:
    return prior_sample("structural", 64, 11)


@pytest.fixture(scope="session")
def ehr_sets() -> np.ndarray:
    return prior_sample("ehr", 64, 12)


# ----------------------------------------------------------------------------- small EHR networks
def identity_couplings(flow):
    """Zero the last layer of every coupling's scale and shift nets: each coupling is then the
    identity, and (without BatchNorm) the flow's density in physical units is the independent
    Gaussian N(y_scaler.mean, diag(y_scaler.std^2)). Returns ``flow``."""
    with torch.no_grad():
        for layer in flow.layers:
            for net in (layer.s, layer.t):
                net[-1].weight.zero_()
                net[-1].bias.zero_()
    return flow


def gaussian_log_density(y: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """log N(y; mean, diag(std^2)) of each row of ``y`` (N, d), nats."""
    z = (np.atleast_2d(np.asarray(y, float)) - mean) / std
    return (-0.5 * z**2 - np.log(std) - 0.5 * np.log(2 * np.pi)).sum(axis=1)


def toy_ehr_networks(n_sets: int, seed: int, flow_rows: int | None = None):
    """Small untrained networks on ``n_sets`` simulated EHR-prior sets (prior seed ``seed``, torch
    seed 0): an emulator (16 hidden, 3 layers), a flow with identity couplings (a Gaussian, see
    :func:`identity_couplings`) standardized on the first ``flow_rows`` outputs (default all) and an
    encoder/decoder (8 hidden, 2 layers each); scalers fitted on the sets.

    Returns ``(flow (eval mode), encoder_decoder, emulator, parameters (n, 23), outputs (n, 16))``.
    """
    from cvsim6 import nets as networks
    from cvsim6.model import solver

    torch.manual_seed(0)
    v = prior_sample("ehr", n_sets, seed)
    y, status = solver.simulate_batch(v)
    assert (status == 0).all()
    emu = networks.Emulator(16, 3)
    emu.x_scaler.fit(v)
    emu.y_scaler.fit(y)
    flow = identity_couplings(networks.RealNVP(hidden=8, blocks=4, layers_per_block=3))
    flow.y_scaler.fit(y[:flow_rows])
    ed = networks.EncoderDecoder(encoder_hidden=8, encoder_layers=2, decoder_hidden=8, decoder_layers=2)
    ed.x_scaler.fit(v)
    ed.y_scaler.fit(y)
    return flow.eval(), ed, emu, v, y


@pytest.fixture(autouse=True)
def one_thread():
    """Small networks on a 2-core machine: one torch thread is fastest and immune to
    oversubscription on a busy host."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """The training tests' synthetic split: (train, test) parquet paths."""
    import training_helpers

    return training_helpers.write_synthetic_split(tmp_path_factory.mktemp("data"))


@pytest.fixture(scope="module")
def emulator(data, tmp_path_factory):
    """The training tests' tiny emulator: (folder, training summary)."""
    import training_helpers

    return training_helpers.train_tiny_emulator(data, tmp_path_factory.mktemp("emu"))
