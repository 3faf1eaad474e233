"""Neural posterior estimation (NPE, sbi) of the 23 parameters from the 16 outputs: the
baseline beside inVAErt, trained on the same simulated training split with the same noise
model, y' = y + eta, eta ~ N(0, diag((delta * s)^2)) (:func:`cvsim6.nets.draw_noise`).

sbi's NPE fits a conditional density q(theta | y') (a masked autoregressive flow by
default) by maximum likelihood over (theta, y') pairs drawn from the prior and the
simulator, one noise draw per training row. The prior is uniform on a box [lo, hi]; the
estimator works in the unbounded coordinates u = logit((theta - lo) / (hi - lo)), where the
prior is a product of standard logistic distributions, so that every sample maps back inside
the box (sbi's leakage rejection in 23 dimensions can otherwise stall). Samples are
returned in physical (registry) units.

Files: :func:`save_npe` writes the estimator's weights, its architecture and the prior box
in one ``.pt`` file that loads with ``weights_only=True``; :func:`load_npe` rebuilds it.
Randomness: ``seed`` fixes the initial weights, sbi's validation split and minibatches
(global torch RNG, restored afterwards) and, separately, each call's samples.
"""
from __future__ import annotations

import logging
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from sbi.inference import NPE, DirectPosterior
from sbi.neural_nets import posterior_nn
from torch.distributions import Independent, SigmoidTransform, TransformedDistribution, Uniform

from cvsim6 import nets as nw
from cvsim6.data.datasets import load_split
from cvsim6.data.priors import prior_bounds
from cvsim6.registry import N_OUTPUTS, N_PARAMETERS
from cvsim6.seeding import derived_seed

log = logging.getLogger(__name__)

#: Format tag of an NPE file.
FORMAT = "cvsim6-npe-1"

#: ``hyper`` keys and defaults: the density estimator (sbi ``posterior_nn``: ``model``,
#: ``hidden_features``, ``num_transforms``) and its training (sbi ``NPE.train``: minibatch
#: ``batch_size``, Adam ``lr``, ``validation_fraction`` held out for early stopping after
#: ``stop_after_epochs`` epochs without improvement, at most ``max_epochs``).
HYPER_DEFAULTS = {"model": "maf", "hidden_features": 50, "num_transforms": 5, "batch_size": 512,
                  "lr": 5.0e-4, "validation_fraction": 0.1, "stop_after_epochs": 20, "max_epochs": 300}


def check_hyper(hyper: dict | None) -> dict:
    """``hyper`` completed with :data:`HYPER_DEFAULTS`; an unknown key raises ValueError."""
    hyper = dict(hyper or {})
    unknown = sorted(set(hyper) - set(HYPER_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown NPE setting(s) {unknown}; expected any of {sorted(HYPER_DEFAULTS)}")
    return {**HYPER_DEFAULTS, **hyper}


def to_unbounded(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """logit((theta - lo) / (hi - lo)); theta must lie strictly inside the box."""
    z = (np.asarray(theta, float) - lo) / (hi - lo)
    if not ((z > 0) & (z < 1)).all():
        i, j = np.argwhere(~((z > 0) & (z < 1)))[0]
        raise ValueError(f"row {i}, parameter {j}: {float(np.asarray(theta)[i, j]):g} is not inside the prior box "
                         f"({lo[j]:g}, {hi[j]:g})")
    return np.log(z) - np.log1p(-z)


def from_unbounded(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_unbounded`: lo + (hi - lo) * sigmoid(u)."""
    return lo + (hi - lo) / (1.0 + np.exp(-np.asarray(u, float)))


class _StandardLogistic(TransformedDistribution):
    """Standard logistic variables (logit of a uniform), with their mean 0 and variance pi^2 / 3."""

    def __init__(self, dim: int):
        super().__init__(Uniform(torch.zeros(dim), torch.ones(dim)), [SigmoidTransform().inv])

    @property
    def mean(self) -> torch.Tensor:
        return torch.zeros(self.event_shape or self.batch_shape)

    @property
    def variance(self) -> torch.Tensor:
        return torch.full(self.event_shape or self.batch_shape, float(np.pi**2 / 3))


def logistic_prior(dim: int = N_PARAMETERS) -> Independent:
    """The uniform box prior in the unbounded coordinates: ``dim`` standard logistic variables."""
    return Independent(_StandardLogistic(dim), 1)


class _NoTracker:
    """sbi's experiment-tracker protocol, doing nothing: the losses go to our CSV instead of
    a TensorBoard folder ``sbi-logs/`` in the working directory."""

    log_dir = None

    def log_metric(self, name, value, step=None) -> None:
        pass

    def log_metrics(self, metrics, step=None) -> None:
        pass

    def log_params(self, params) -> None:
        pass

    def add_figure(self, name, figure, step=None) -> None:
        pass

    def flush(self) -> None:
        pass


def _builder(h: dict):
    return posterior_nn(model=h["model"], hidden_features=int(h["hidden_features"]),
                        num_transforms=int(h["num_transforms"]), z_score_theta="independent",
                        z_score_x="independent")


class NPEPosterior:
    """A trained NPE with its prior box: ``sample(y, n, seed)`` gives parameters in physical units."""

    def __init__(self, estimator: torch.nn.Module, lo: np.ndarray, hi: np.ndarray, hyper: dict, info: dict):
        self.estimator = estimator.eval()
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.hyper, self.info = dict(hyper), dict(info)
        with torch.random.fork_rng(devices=[]):
            self.posterior = DirectPosterior(estimator, logistic_prior(len(self.lo)))

    @torch.no_grad()
    def sample(self, y: np.ndarray, n: int, seed: int = 0, chunk: int = 200) -> np.ndarray:
        """``n`` posterior samples for each observation row of ``y`` (m, 16): (m, n, 23), physical
        units. The same seed gives the same samples; the global torch RNG is left as it was."""
        y = np.atleast_2d(np.asarray(y, float))
        if y.shape[1] != N_OUTPUTS or not np.isfinite(y).all():
            raise ValueError(f"observations must be finite and have {N_OUTPUTS} columns; got shape {y.shape}")
        out = np.empty((len(y), int(n), len(self.lo)))
        with torch.random.fork_rng(devices=[]), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Capping max_sampling_batch_size")  # memory only
            torch.manual_seed(int(seed))
            for i0 in range(0, len(y), chunk):
                x = torch.as_tensor(y[i0:i0 + chunk], dtype=torch.float32)
                u = self.posterior.sample_batched((int(n),), x=x, show_progress_bars=False)  # (n, m, d)
                out[i0:i0 + chunk] = from_unbounded(u.transpose(0, 1).double().numpy(), self.lo, self.hi)
        return out


def fit_npe(theta: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray, hyper: dict | None = None,
            seed: int = 0, progress: bool = False) -> tuple[NPEPosterior, pd.DataFrame]:
    """Train sbi's NPE on pairs (theta (n, 23) physical, y (n, 16) already noisy).

    Returns the posterior and the per-epoch losses (``epoch``, ``train_loss``, ``test_loss``:
    sbi's validation loss, negative log-likelihood in nats; ``seconds``). ``progress`` prints
    sbi's epoch counter (to stdout, the rule's log in the workflow).
    """
    h = check_hyper(hyper)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    u = torch.as_tensor(to_unbounded(theta, lo, hi), dtype=torch.float32)
    x = torch.as_tensor(np.asarray(y, float), dtype=torch.float32)
    t0, c0 = time.perf_counter(), time.process_time()
    with torch.random.fork_rng(devices=[]), warnings.catch_warnings():
        # sbi warns when max_epochs ends training before its early stop: the losses CSV shows it
        warnings.filterwarnings("ignore", message="Maximum number of epochs")
        torch.manual_seed(int(seed))
        inference = NPE(prior=logistic_prior(len(lo)), density_estimator=_builder(h), show_progress_bars=bool(progress),
                        tracker=_NoTracker())
        inference.append_simulations(u, x)
        estimator = inference.train(training_batch_size=int(h["batch_size"]), learning_rate=float(h["lr"]),
                                    validation_fraction=float(h["validation_fraction"]),
                                    stop_after_epochs=int(h["stop_after_epochs"]),
                                    max_num_epochs=int(h["max_epochs"]))
    s = inference._summary
    n_ep = len(s["training_loss"])
    if n_ep >= int(h["max_epochs"]):
        log.warning("NPE stopped at max_epochs = %d before its validation loss stopped improving",
                    int(h["max_epochs"]))
    losses = pd.DataFrame({"epoch": np.arange(1, n_ep + 1), "train_loss": s["training_loss"],
                           "test_loss": s["validation_loss"][:n_ep],
                           "seconds": list(s.get("epoch_durations_sec", [np.nan] * n_ep))[:n_ep]})
    info = {"epochs_done": n_ep, "best_validation_loss": float(min(s["validation_loss"])),
            "train_seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
            "n_train": len(u), "seed": int(seed), "torch": str(torch.__version__)}
    return NPEPosterior(estimator, lo, hi, h, info), losses


def save_npe(post: NPEPosterior, path: str | Path) -> None:
    """One ``.pt`` file (written atomically): format, hyper, prior box, weights, info."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "hyper": post.hyper, "lo": post.lo.tolist(), "hi": post.hi.tolist(),
               "state_dict": {k: v.detach().cpu() for k, v in post.estimator.state_dict().items()},
               "info": post.info}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def load_npe(path: str | Path) -> NPEPosterior:
    """Rebuild an :class:`NPEPosterior` saved by :func:`save_npe`."""
    payload = torch.load(path, map_location="cpu", weights_only=True)
    if payload.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file (format={payload.get('format')!r})")
    h = check_hyper(payload["hyper"])
    lo = np.asarray(payload["lo"], float)
    # any batch builds the architecture; the z-scoring buffers come from the state dict
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        estimator = _builder(h)(torch.randn(64, len(lo)), torch.randn(64, N_OUTPUTS))
    estimator.load_state_dict(payload["state_dict"])
    return NPEPosterior(estimator, lo, np.asarray(payload["hi"], float), h, payload.get("info", {}))


def train_npe(train: str, model: str, losses: str, prior: dict, hyper: dict, noise_level: float,
              seed: int, threads: int = 1) -> dict:
    """Workflow step: NPE on the training split, one noise draw of level ``noise_level`` (delta)
    per row (seeded), on ``threads`` CPU threads; writes ``model`` and ``losses`` (CSV;
    :func:`cvsim6.reporting.loss_figures.plot_training_losses` draws it)."""
    torch.set_num_threads(int(threads))
    v, y = load_split(train)
    lo, hi = prior_bounds(prior)
    gen = torch.Generator().manual_seed(derived_seed(seed, 3))
    y_noisy = y + nw.draw_noise(len(y), float(noise_level), gen).numpy()
    post, hist = fit_npe(v, y_noisy, lo, hi, hyper, seed=seed, progress=True)
    post.info.update(noise_level=float(noise_level), label=f"delta={noise_level:g}")
    save_npe(post, model)
    Path(losses).parent.mkdir(parents=True, exist_ok=True)
    hist.to_csv(losses, index=False)
    log.info("NPE delta=%g: %d epochs, %.0f s wall, %.0f s CPU, best validation NLL %.4g",
             noise_level, post.info["epochs_done"], post.info["train_seconds"], post.info["cpu_seconds"],
             post.info["best_validation_loss"])
    return post.info
