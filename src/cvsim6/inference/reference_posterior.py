"""Reference posteriors by MCMC with the exact simulator, and how to compare samples with them.

Target: the uniform prior box ``[lo, hi]`` (registry units) and the paper's noise model, a
Gaussian likelihood of the *observed* outputs with standard deviation ``delta * s_k``
(``s_k`` the registry noise std of output k, its unit). The chain runs in the unit box
``u = (theta - lo) / (hi - lo)``; the posterior density there is the same up to a constant.

Sampler: emcee's ensemble sampler (Foreman-Mackey et al. 2013), a maintained, dependency-free
library whose walkers are evaluated as one batch (``vectorize=True``) by the batch simulator,
with differential-evolution moves (ter Braak & Vrugt 2008: 80% DE, 20% DE snooker), which
follow the long, thin, non-identifiable ridges of this posterior far better than the default
stretch move (a trial on one case: autocorrelation ~120 steps against ~200 and a stuck
ensemble). A proposal outside the box is rejected without a simulation. Start: the walkers
most likely among prior draws, moved onto the ridge by a few batched Levenberg-Marquardt
steps; the first half of the chain is discarded. The chain is extended in blocks until
R-hat and ESS (ArviZ: rank-normalized split R-hat; bulk and tail ESS; walkers as chains)
reach their targets or ``max_steps`` is spent.
"""
from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cvsim6.model import solver

log = logging.getLogger(__name__)

#: Fraction of the unit box kept between a Levenberg-Marquardt start and the box's faces.
START_MARGIN = 1e-4
#: Width of the band along each face of the unit box in which a start's coordinate is redrawn.
FACE_BAND = 1e-2
#: Forward-difference step of the start's Jacobian, in prior-box units.
START_STEP = 1e-4


def _arviz():
    """ArviZ, imported quietly (its import prints a FutureWarning about a refactor)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz

    return arviz


def simulator_function(simulator: dict) -> Callable[[np.ndarray], np.ndarray]:
    """``f(theta (N, 23)) -> (N, 16)`` outputs on the batch path with the workflow's simulator
    settings; NaN rows where the simulator flags a set (registry units)."""
    def f(theta: np.ndarray) -> np.ndarray:
        out, status = solver.simulate_batch(theta, steps_per_cycle=simulator["steps_per_cycle"],
                                            n_cycles=simulator["n_cycles"],
                                            window_cycles=simulator["window_cycles"], invalid="flag")
        out[status != 0] = np.nan
        return out

    return f


@dataclass
class BoxPosterior:
    """Unnormalized log posterior on the unit box: uniform prior on ``[lo, hi]``, Gaussian
    likelihood of the finite entries of ``y_obs`` with standard deviations ``sigma`` (their
    units); ``forward`` maps (N, d) parameters to (N, m) outputs (NaN: no output)."""

    forward: Callable[[np.ndarray], np.ndarray]
    y_obs: np.ndarray
    sigma: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    evaluations: int = field(default=0, init=False)

    def __post_init__(self):
        self.y_obs = np.asarray(self.y_obs, float)
        self.sigma = np.asarray(self.sigma, float)
        self.lo, self.hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        self.observed = np.isfinite(self.y_obs)
        if not self.observed.any():
            raise ValueError("no observed output: every entry of y_obs is NaN")
        if not (self.sigma[self.observed] > 0).all():
            raise ValueError(f"likelihood standard deviations must be > 0, got {self.sigma[self.observed]}")
        if not (self.hi > self.lo).all():
            j = int(np.argmin(self.hi - self.lo))
            raise ValueError(f"prior box of parameter {j} is empty: [{self.lo[j]}, {self.hi[j]}]")

    @property
    def ndim(self) -> int:
        return len(self.lo)

    def to_physical(self, u: np.ndarray) -> np.ndarray:
        """Unit-box coordinates -> parameters (registry units)."""
        return self.lo + (self.hi - self.lo) * np.asarray(u, float)

    def to_unit(self, theta: np.ndarray) -> np.ndarray:
        """Parameters (registry units) -> unit-box coordinates."""
        return (np.asarray(theta, float) - self.lo) / (self.hi - self.lo)

    def residuals(self, u: np.ndarray) -> np.ndarray:
        """Standardized residuals (N, observed) of the observed outputs; NaN rows where the
        forward model gives no output."""
        u = np.atleast_2d(u)
        self.evaluations += len(u)
        y = np.asarray(self.forward(self.to_physical(u)), float)
        return (y[:, self.observed] - self.y_obs[self.observed]) / self.sigma[self.observed]

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        """Log posterior (N,) up to a constant; -inf outside the open box or without output.
        Points outside the box are not simulated."""
        u = np.atleast_2d(np.asarray(u, float))
        lp = np.full(len(u), -np.inf)
        inside = ((u > 0) & (u < 1)).all(axis=1)
        if inside.any():
            chi2 = (self.residuals(u[inside]) ** 2).sum(axis=1)
            lp[inside] = np.where(np.isfinite(chi2), -0.5 * chi2, -np.inf)
        return lp


def _jacobians(post: BoxPosterior, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standardized residuals (W, m) at ``u`` (W, d) and their forward-difference Jacobians
    (W, m, d) in unit-box coordinates: one batch of W (d + 1) simulations."""
    n, d = u.shape
    r0 = post.residuals(u)
    rj = post.residuals((u[:, None, :] + START_STEP * np.eye(d)[None]).reshape(-1, d)).reshape(n, d, -1)
    return r0, np.transpose((rj - r0[:, None, :]) / START_STEP, (0, 2, 1))


def start_walkers(post: BoxPosterior, n_walkers: int, rng: np.random.Generator, prior_draws: int = 4000,
                  iterations: int = 12) -> np.ndarray:
    """Starting points (n_walkers, d) in the unit box: the ``n_walkers`` most likely of
    ``prior_draws`` uniform draws, each improved by ``iterations`` batched Levenberg-Marquardt
    steps, then each replaced by a draw from its local Gaussian (Laplace) approximation
    N(u, (J'J + 12 I)^-1) (12 I: the precision of the uniform prior), so that the walkers start
    with about the posterior's width in every direction: an ensemble's moves (differences of
    walkers) widen a collapsed direction only slowly. A coordinate outside the box or within
    :data:`FACE_BAND` of a face is redrawn uniformly in that band."""
    if prior_draws < n_walkers:
        raise ValueError(f"prior_draws = {prior_draws} must be at least n_walkers = {n_walkers}")
    draws = rng.random((int(prior_draws), post.ndim))
    lp = post.log_prob(draws)
    if np.isfinite(lp).sum() < n_walkers:
        raise ValueError(f"only {int(np.isfinite(lp).sum())} of {prior_draws} prior draws simulated; "
                         f"need {n_walkers} starting points (raise start_prior_draws)")
    u = draws[np.argsort(-lp, kind="stable")[:n_walkers]].copy()
    eye = np.eye(post.ndim)
    damping = np.full(n_walkers, 1e-2)
    for _ in range(int(iterations)):
        r0, J = _jacobians(post, u)
        JtJ = np.einsum("wmi,wmj->wij", J, J)
        grad = np.einsum("wmi,wm->wi", J, r0)
        A = JtJ + damping[:, None, None] * (np.einsum("wii->wi", JtJ)[:, :, None] * eye + 1e-6 * eye)
        ok_rows = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(grad).all(axis=1)
        step = np.zeros_like(u)
        if ok_rows.any():
            step[ok_rows] = -np.linalg.solve(A[ok_rows], grad[ok_rows][..., None])[..., 0]
        trial = np.clip(u + step, START_MARGIN, 1 - START_MARGIN)
        c0, c1 = (r0**2).sum(axis=1), (post.residuals(trial) ** 2).sum(axis=1)
        better = np.isfinite(c1) & (~np.isfinite(c0) | (c1 < c0))
        u[better] = trial[better]
        damping = np.where(better, damping / 3, damping * 4)
    _, J = _jacobians(post, u)
    precision = np.einsum("wmi,wmj->wij", J, J) + 12.0 * eye
    fine = np.isfinite(precision).all(axis=(1, 2))
    z = rng.standard_normal(u.shape)
    if fine.any():
        chol = np.linalg.cholesky(np.linalg.inv(precision[fine]))
        u[fine] = u[fine] + np.einsum("wij,wj->wi", chol, z[fine])
    low, high = u < FACE_BAND, u > 1 - FACE_BAND
    u[low] = rng.uniform(START_MARGIN, FACE_BAND, int(low.sum()))
    u[high] = rng.uniform(1 - FACE_BAND, 1 - START_MARGIN, int(high.sum()))
    return u


def convergence(chain: np.ndarray) -> dict[str, np.ndarray]:
    """ArviZ diagnostics of ``chain`` (walkers, draws, d), walkers as chains: rank-normalized
    split ``rhat`` (inf where a parameter is constant: the walkers collapsed), ``ess_bulk`` and
    ``ess_tail`` per parameter (d,)."""
    az = _arviz()
    data = az.convert_to_dataset(np.asarray(chain, float))
    name = list(data.data_vars)[0]
    rhat = np.asarray(az.rhat(data)[name].values, float)
    return {"rhat": np.where(np.isnan(rhat), np.inf, rhat),  # NaN: a parameter no walker moves
            "ess_bulk": np.asarray(az.ess(data, method="bulk")[name].values, float),
            "ess_tail": np.asarray(az.ess(data, method="tail")[name].values, float)}


def run_ensemble(post: BoxPosterior, start: np.ndarray, seed: int, min_steps: int, max_steps: int,
                 check_every: int, rhat_max: float = 1.05, ess_min: float = 400.0,
                 progress: bool = False) -> dict:
    """emcee with DE moves from ``start`` (walkers, d), seeded, extended by ``check_every``
    steps from ``min_steps`` on until, over the second half of the chain, every parameter has
    R-hat <= ``rhat_max`` and bulk and tail ESS >= ``ess_min``, or ``max_steps`` are run.

    Returns ``chain`` (walkers, kept draws, d; unit box: the second half), the diagnostics of
    :func:`convergence`, ``steps``, ``acceptance`` (mean over walkers), ``evaluations``
    (simulations), ``converged`` and ``mcmc_cpu_seconds`` (process CPU time of the sampling)."""
    import emcee

    start = np.asarray(start, float)
    n_walkers = start.shape[0]
    if not 0 < int(min_steps) <= int(max_steps) or int(check_every) < 1:
        raise ValueError(f"need 0 < min_steps ({min_steps}) <= max_steps ({max_steps}) and check_every "
                         f"({check_every}) >= 1")
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(n_walkers, post.ndim, post.log_prob, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(np.random.SeedSequence(int(seed)).generate_state(1)[0]).get_state()
    cpu0, evals0 = time.process_time(), post.evaluations
    state, steps, target = start, 0, int(min_steps)
    while True:
        state = sampler.run_mcmc(state, target - steps, progress=progress)
        steps = target
        chain = np.transpose(sampler.get_chain()[steps // 2:], (1, 0, 2))
        diag = convergence(chain)
        ess = np.minimum(diag["ess_bulk"], diag["ess_tail"])
        converged = bool((diag["rhat"] <= rhat_max).all() and (ess >= ess_min).all())
        log.info("%d steps: R-hat max %.3f, ESS min %.0f, acceptance %.2f", steps, diag["rhat"].max(), ess.min(),
                 sampler.acceptance_fraction.mean())
        if converged or steps >= int(max_steps):
            break
        target = min(int(max_steps), steps + int(check_every))
    return dict(chain=chain, steps=steps, acceptance=float(sampler.acceptance_fraction.mean()),
                evaluations=post.evaluations - evals0, converged=converged,
                mcmc_cpu_seconds=time.process_time() - cpu0, **diag)


def thin(chain: np.ndarray, keep: int) -> np.ndarray:
    """At most ``keep`` draws (n, d) of ``chain`` (walkers, draws, d): every k-th step of every
    walker, k the smallest stride that fits."""
    w, n, d = chain.shape
    stride = max(1, int(np.ceil(w * n / int(keep))))
    return chain[:, ::stride].reshape(-1, d)[: int(keep)]


def c2st_accuracy(reference: np.ndarray, samples: np.ndarray, seed: int, n_folds: int = 5) -> float:
    """Classifier two-sample test (sbi's ``c2st``: random forest, ``n_folds``-fold
    cross-validated accuracy, z-scored): 0.5 when ``samples`` (n, d) cannot be told from
    ``reference`` (N, d), 1 when always. The reference is subsampled (seeded) to n rows, so
    that both classes weigh the same; non-finite rows of ``samples`` are dropped."""
    import torch
    from sbi.utils.metrics import c2st

    samples = np.asarray(samples, float)
    samples = samples[np.isfinite(samples).all(axis=1)]
    reference = np.asarray(reference, float)
    n = min(len(samples), len(reference))
    if n < 2 * int(n_folds):
        return float("nan")
    rng = np.random.default_rng(int(seed))
    ref = reference[np.sort(rng.choice(len(reference), size=n, replace=False))]
    got = samples[np.sort(rng.choice(len(samples), size=n, replace=False))]
    acc = c2st(torch.as_tensor(ref, dtype=torch.float32), torch.as_tensor(got, dtype=torch.float32),
               seed=int(seed) % (2**31), n_folds=int(n_folds))
    return float(np.asarray(acc).reshape(-1)[0])


def compare_moments(reference: np.ndarray, samples: np.ndarray, lo: np.ndarray, hi: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per parameter (d,): the difference of the posterior means (samples - reference) in
    prior-box units (fractions of ``hi - lo``), and the ratio of the posterior standard
    deviations (samples / reference; > 1 wider than the reference)."""
    samples = np.asarray(samples, float)
    samples = samples[np.isfinite(samples).all(axis=1)]
    width = np.asarray(hi, float) - np.asarray(lo, float)
    if len(samples) < 2:
        nan = np.full(len(width), np.nan)
        return nan, nan
    reference = np.asarray(reference, float)
    diff = (samples.mean(axis=0) - reference.mean(axis=0)) / width
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = samples.std(axis=0) / reference.std(axis=0)
    return diff, ratio
