"""Shared fixtures: parameter sets from both priors of the paper, seeded."""
import numpy as np
import pytest
import torch

from cvsim6.data import priors
from cvsim6 import registry


@pytest.fixture(scope="session")
def default_params() -> np.ndarray:
    return registry.default_parameters()


def prior_sample(study: str, n: int, seed: int) -> np.ndarray:
    lo, hi = priors.prior_bounds(priors.PAPER_PRIORS[study])
    return priors.sample_uniform(lo, hi, n, np.random.default_rng(seed))


@pytest.fixture(scope="session")
def structural_sets() -> np.ndarray:
    return prior_sample("structural", 64, 11)


@pytest.fixture(scope="session")
def ehr_sets() -> np.ndarray:
    return prior_sample("ehr", 64, 12)


@pytest.fixture(autouse=True)
def one_thread():
    """Small networks on a 2-core machine: one torch thread is fastest and immune to
    oversubscription on a busy host."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
