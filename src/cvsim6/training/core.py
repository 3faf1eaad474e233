"""Resumable, seeded training of the three inVAErt stages (file-based, for Snakemake).

Entry points (all paths are strings; datasets are Parquet splits with the 23 parameter and
16 output columns in clinical units):

* :func:`train_emulator` -- ``NN_e``, MSE in standardized space, never with noise.
* :func:`train_flow` -- ``NN_f``, negative log-likelihood of the (noisy) standardized outputs.
* :func:`train_encoder_decoder` -- ``NN_v`` + ``NN_d`` through the frozen trained emulator.

``hyper`` keys
--------------
Common (required): ``epochs`` (int), ``batch_size`` (int), ``lr`` (initial Adam learning rate).
Common (optional): ``lr_schedule`` ("step", default: StepLR with ``lr_step`` epochs per decay
by ``lr_gamma``, both then required; "cosine": linear warm-up over ``warmup_epochs`` (default
0), then a cosine down to ``lr * lr_final`` (default 0) in the last epoch), ``weight_decay``
(Adam L2 penalty, default 0), ``grad_clip`` (max global gradient norm, 0 = off, default 0; the
paper's code clips the structural flow at 10; when on, a step whose gradient norm is not finite,
e.g. overflowed by a loss spike, is skipped: no update, left out of the epoch's mean loss,
counted in the losses CSV's ``skipped_steps`` column and logged), ``eval_every`` (epochs between test-loss
evaluations, default 1; the last epoch is always evaluated), ``keep_best`` (save the weights of
the evaluation with the lowest test loss, default False: the last epoch's), ``dtype``
("float32", default, or "float64", as the paper's code), ``restarts`` (default 1; k > 1: the
best of k initializations, each trained the first ``restart_epochs`` epochs of the schedule,
the one with the lowest test loss there trains on; see :func:`_train`).

* emulator: ``hidden``, ``layers`` (Linear layers in total); optional ``activation`` ("silu"),
  ``variance_floor`` (default None: the loss is the MSE of the standardized outputs, as the
  paper's; a number f > 0: the errors are first multiplied by ``W = V diag(sqrt(max(1, f/lam)))
  V^T``, with ``lam, V`` the eigenvalues and vectors of the standardized training outputs'
  covariance ``C``, so the loss sees the outputs as if no direction of ``C`` had a variance below
  f (``W C W`` has the eigenvalues ``max(lam, f)``); directions with variance >= f weigh as in the
  plain MSE. P_r_sys and P_pa_sys differ by the pulmonary-valve drop, about 2% of either one's
  spread: their difference is C's smallest direction (variance ~6e-5), which the plain MSE
  weighs so little that it is learned last. The losses CSV then has ``train_mse``/``test_mse``
  columns, the plain MSE, beside the weighted loss); ``relative_weight`` (default 0: every
  training row weighs the same; a in (0, 1]: row i's squared error is weighted by
  ``(1 - a) + a * (1/|y_i|^2) / mean_j(1/|y_j|^2)``, with ``|y|`` the Euclidean norm of the
  physical outputs and the mean over the training rows, so the loss mixes the standardized MSE
  with the squared error relative to the output vector's norm, the paper's relative l2 metric.
  Without it the relative l2 error peaks where ``|y|`` is smallest (the EHR prior's low-SVR
  corner, ``|y|`` ~300 against a median of ~1,200); the weights average 1 over the training rows,
  the test rows use the same normalization. The losses CSV then has the ``train_mse``/``test_mse``
  columns too).
* flow: ``hidden``, ``blocks``, ``layers_per_block`` (Linear layers per s/t net, paper 4),
  ``batchnorm`` (bool); optional ``noisy_scaling`` (see below).
* encoder_decoder: ``latent_dim``, ``encoder_hidden``, ``encoder_layers``, ``decoder_hidden``,
  ``decoder_layers``, ``beta_d``, ``beta_v``, ``beta_r``; optional ``reduction`` ("sum":
  per-sample squared norms averaged over the batch, the paper's equation; "mse": mean over
  batch and components, the paper's public code), ``activation`` ("silu"), ``reeval_target``
  ("noisy", default: the re-evaluation term compares NN_e(NN_d(y', w)) with the noisy y';
  "clean": with the clean y, as the paper's public code), ``noisy_scaling``, ``kl_warmup_epochs``
  (default 0: the KL weight is ``beta_v`` throughout; k > 0: ``beta_v * e / k`` in epoch e =
  1..k, then ``beta_v``, so the encoder learns to carry information before the KL term presses
  on it; test losses, and so ``keep_best``, always use the full ``beta_v``), ``logvar_max``
  (default None; a number > 0 caps the encoder's log-variance, see ``EncoderDecoder``),
  ``log_parameters`` (default False, the paper's; True: the encoder sees and the decoder gives
  the logarithm of every parameter whose training values are all positive, standardized, so
  that no decoded set has a compliance, resistance or volume <= 0; the decoder's squared error
  is then measured on those logarithms), ``beta_prior`` (default 0, the paper's loss; > 0 adds
  ``beta_prior * E||y - NN_e(NN_d(y', w))||^2`` with ``w ~ N(0, I)`` drawn afresh each epoch,
  the latent draws an inversion decodes, beside the re-evaluation term's encoder draws; same
  target; the losses CSV then has ``train_prior_reeval``/``test_prior_reeval`` columns).
* ``noisy_scaling`` (flow, encoder/decoder; default False): standardize the outputs with the
  std of the noisy outputs, ``sqrt(std^2 + (delta*s)^2)`` (the paper's public code), instead of
  the clean training outputs' std.

Unknown keys raise ``ValueError``.

Training procedure
------------------
* Standardizers are fitted on the training split (clean outputs) and saved in the model.
* Noise (flow, encoder/decoder, re-evaluation term; delta = ``noise_level``): once per epoch a
  fresh draw ``eta ~ N(0, diag((delta*s)^2))`` in physical units for the whole training set,
  added to y and then standardized (``y_std + eta / std_y``). Never for the emulator.
* Randomness: ``torch.manual_seed(seed)`` before building the model (initial weights); one CPU
  ``torch.Generator`` (derived from ``seed``) draws, per epoch and in this order, the noise, the
  reparameterization ``eps`` (encoder/decoder) and the minibatch permutation. Test losses use
  one fixed noise/eps draw from a second derived generator. Results are bit-reproducible on
  CPU for a fixed thread count.
* Minibatches: whole tensors on the device, indexed by a permutation; a trailing batch of a
  single sample is dropped (BatchNorm needs two).
* Adam (``fused=True`` when supported) + the learning-rate schedule stepped once per epoch.
* Losses CSV columns: ``epoch`` (1-based), ``train_loss`` (sample-weighted mean over the
  epoch's minibatches, in train mode), ``test_loss`` (eval mode, full test split; NaN in
  epochs not evaluated), ``lr`` (learning rate used in that epoch), ``seconds`` and ``cpu_seconds``
  (wall and process CPU time of that epoch; the model file holds no timings, so it is
  bit-reproducible), then per-term columns for the encoder/decoder
  (unweighted ``decoder``, ``kl``, ``reeval`` terms).
* Checkpoints (model, optimizer, scheduler, RNG states, history, epoch) every
  ``checkpoint_every`` epochs and at the end, written atomically to ``checkpoint`` (default
  ``model + ".ckpt"``). A rerun with the same arguments resumes from it and yields the same
  final weights as an uninterrupted run. A checkpoint whose fingerprint (stage, hyper, seed,
  noise level, data and emulator contents, the training code's digest) differs is ignored and
  overwritten. A non-finite loss ends the run with ``FloatingPointError``; the last good
  checkpoint stays, the failed state goes to ``<checkpoint>.nonfinite`` for inspection.
"""
from __future__ import annotations

import csv
import hashlib
import json
import logging
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cvsim6 import nets as nw
from cvsim6.data.datasets import load_split
from cvsim6.registry import noise_std

log = logging.getLogger(__name__)

_COMMON_REQUIRED = ("epochs", "batch_size", "lr")
_COMMON_OPTIONAL = {"weight_decay": 0.0, "grad_clip": 0.0, "lr_schedule": "step", "lr_step": None,
                    "lr_gamma": None, "warmup_epochs": 0, "lr_final": 0.0, "eval_every": 1,
                    "keep_best": False, "dtype": "float32", "restarts": 1, "restart_epochs": 0}
_DTYPES = {"float32": torch.float32, "float64": torch.float64}
HYPER_KEYS: dict[str, tuple[tuple[str, ...], dict]] = {
    "emulator": (_COMMON_REQUIRED + ("hidden", "layers"),
                 {**_COMMON_OPTIONAL, "activation": "silu", "variance_floor": None, "relative_weight": 0.0,
                  "linear_skip": False, "log_inputs": False}),
    "flow": (_COMMON_REQUIRED + ("hidden", "blocks", "layers_per_block", "batchnorm"),
             {**_COMMON_OPTIONAL, "noisy_scaling": False}),
    "encoder_decoder": (
        _COMMON_REQUIRED + ("latent_dim", "encoder_hidden", "encoder_layers", "decoder_hidden",
                            "decoder_layers", "beta_d", "beta_v", "beta_r"),
        {**_COMMON_OPTIONAL, "reduction": "sum", "activation": "silu", "reeval_target": "noisy",
         "noisy_scaling": False, "kl_warmup_epochs": 0, "logvar_max": None, "log_parameters": False,
         "beta_prior": 0.0},
    ),
}
_EVAL_CHUNK = 65536


# ----------------------------------------------------------------------------- helpers
def _is_real(x) -> bool:
    """A finite int or float, not a bool (YAML's ``true`` is an int to Python)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_hyper(stage: str, hyper: dict) -> dict:
    """Validated copy of ``hyper`` for ``stage`` with optional keys filled in."""
    required, optional = HYPER_KEYS[stage]
    missing = [k for k in required if k not in hyper]
    unknown = sorted(set(hyper) - set(required) - set(optional))
    if missing or unknown:
        raise ValueError(f"{stage} hyperparameters: missing {missing}, unknown {unknown}")
    h = {**optional, **hyper}
    if h["lr_schedule"] not in ("step", "cosine"):
        raise ValueError(f"{stage} hyperparameter lr_schedule must be 'step' or 'cosine', got {h['lr_schedule']!r}")
    if h["lr_schedule"] == "step" and (h["lr_step"] is None or h["lr_gamma"] is None):
        raise ValueError(f"{stage}: lr_schedule 'step' needs lr_step and lr_gamma, got {h['lr_step']!r}, {h['lr_gamma']!r}")
    if h["dtype"] not in _DTYPES:
        raise ValueError(f"{stage} hyperparameter dtype must be one of {sorted(_DTYPES)}, got {h['dtype']!r}")
    positive = ["epochs", "batch_size", "eval_every"] + (["lr_step"] if h["lr_schedule"] == "step" else [])
    for k in positive:
        if int(h[k]) != h[k] or h[k] < 1:
            raise ValueError(f"{stage} hyperparameter {k} must be a positive integer, got {h[k]!r}")
    if int(h["warmup_epochs"]) != h["warmup_epochs"] or not 0 <= h["warmup_epochs"] < h["epochs"]:
        raise ValueError(f"{stage} hyperparameter warmup_epochs must be an integer in [0, epochs), got {h['warmup_epochs']!r}")
    if int(h["restarts"]) != h["restarts"] or h["restarts"] < 1:
        raise ValueError(f"{stage} hyperparameter restarts must be a positive integer, got {h['restarts']!r}")
    if h["restarts"] > 1 and (int(h["restart_epochs"]) != h["restart_epochs"]
                              or not 1 <= h["restart_epochs"] < h["epochs"]
                              or h["restart_epochs"] % h["eval_every"]):
        raise ValueError(f"{stage} hyperparameter restart_epochs must be an integer in [1, epochs) and a multiple of "
                         f"eval_every ({h['eval_every']}) when restarts > 1, got {h['restart_epochs']!r}")
    if not 0.0 <= float(h["lr_final"]) <= 1.0:
        raise ValueError(f"{stage} hyperparameter lr_final must be in [0, 1], got {h['lr_final']!r}")
    f = h["variance_floor"] if stage == "emulator" else None
    if f is not None and not (_is_real(f) and f > 0):
        raise ValueError(f"emulator hyperparameter variance_floor must be null or a number > 0, got {f!r}")
    a = h["relative_weight"] if stage == "emulator" else 0.0
    if not (_is_real(a) and 0.0 <= a <= 1.0):
        raise ValueError(f"emulator hyperparameter relative_weight must be a number in [0, 1], got {a!r}")
    for k in {"emulator": ("linear_skip", "log_inputs"), "encoder_decoder": ("log_parameters",)}.get(stage, ()):
        if not isinstance(h[k], bool):
            raise ValueError(f"{stage} hyperparameter {k} must be true or false, got {h[k]!r}")
    if stage == "encoder_decoder" and h["reduction"] not in ("sum", "mse"):
        raise ValueError(f"reduction must be 'sum' or 'mse', got {h['reduction']!r}")
    if stage == "encoder_decoder" and (int(h["kl_warmup_epochs"]) != h["kl_warmup_epochs"]
                                       or not 0 <= h["kl_warmup_epochs"] <= h["epochs"]):
        raise ValueError(f"encoder_decoder hyperparameter kl_warmup_epochs must be an integer in [0, epochs], "
                         f"got {h['kl_warmup_epochs']!r}")
    if stage == "encoder_decoder" and h["logvar_max"] is not None and not (_is_real(h["logvar_max"])
                                                                          and h["logvar_max"] > 0):
        raise ValueError(f"encoder_decoder hyperparameter logvar_max must be null or a number > 0, "
                         f"got {h['logvar_max']!r}")
    if stage == "encoder_decoder" and not (_is_real(h["beta_prior"]) and h["beta_prior"] >= 0):
        raise ValueError(f"encoder_decoder hyperparameter beta_prior must be a number >= 0, got {h['beta_prior']!r}")
    if stage == "encoder_decoder" and h["reeval_target"] not in ("noisy", "clean"):
        raise ValueError(f"reeval_target must be 'noisy' or 'clean', got {h['reeval_target']!r}")
    return h


def resolve_device(device: str = "auto") -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; anything else is passed to torch.device."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def make_optimizer(params, lr: float, weight_decay: float, device: torch.device) -> torch.optim.Adam:
    """Adam with ``fused=True`` when the device supports it, else the default implementation."""
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay)


def make_scheduler(opt: torch.optim.Optimizer, hyper: dict) -> torch.optim.lr_scheduler.LRScheduler:
    """Learning-rate schedule stepped once per epoch. ``"step"``: StepLR (``lr_step``,
    ``lr_gamma``). ``"cosine"``: linear warm-up over ``warmup_epochs`` epochs, then a cosine
    from ``lr`` down to ``lr * lr_final`` in the last epoch."""
    if hyper["lr_schedule"] == "step":
        return torch.optim.lr_scheduler.StepLR(opt, step_size=int(hyper["lr_step"]), gamma=float(hyper["lr_gamma"]))
    warm, total, final = int(hyper["warmup_epochs"]), int(hyper["epochs"]), float(hyper["lr_final"])

    def factor(epoch: int) -> float:  # epoch = epochs completed before this one
        if epoch < warm:
            return (epoch + 1) / (warm + 1)
        t = min(1.0, (epoch - warm) / max(1, total - warm - 1))
        return final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * t))

    return torch.optim.lr_scheduler.LambdaLR(opt, factor)


def derived_seed(seed: int, stream: int) -> int:
    """Independent 63-bit seed for random stream ``stream`` of master ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(stream)]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _to_device(a: np.ndarray | torch.Tensor, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return torch.as_tensor(a).to(dtype=dtype).to(device)


def _std_noise(n: int, noise_level: float, generator: torch.Generator, y_std_scale: torch.Tensor) -> torch.Tensor | None:
    """Per-sample noise in standardized units, (n, 16) float64 CPU, or None when delta == 0."""
    if noise_level == 0:
        return None
    return nw.draw_noise(n, noise_level, generator) / y_std_scale


# ----------------------------------------------------------------------------- stages
class _Stage:
    """What the generic loop needs from one training stage."""

    name = ""
    parts: tuple[str, ...] = ()
    model: nn.Module

    def __init__(self, n_train: int, device: torch.device, dtype: torch.dtype = torch.float32):
        self.n_train, self.device, self.dtype = n_train, device, dtype

    def tensor(self, a) -> torch.Tensor:
        """``a`` on the stage's device in its dtype."""
        return _to_device(a, self.device, self.dtype)

    def begin_epoch(self, generator: torch.Generator, epoch: int = 0) -> None:
        """Draw this epoch's random inputs (noise, eps) from ``generator``; ``epoch`` is the
        0-based index of the epoch about to run."""

    def batch_loss(self, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        raise NotImplementedError

    def evaluate(self) -> tuple[float, dict[str, float]]:
        raise NotImplementedError


def _chunked_mean(n: int, fn: Callable[[slice], tuple[torch.Tensor, dict]]) -> tuple[float, dict[str, float]]:
    total, parts = 0.0, {}
    for start in range(0, n, _EVAL_CHUNK):
        sl = slice(start, min(n, start + _EVAL_CHUNK))
        w = (sl.stop - sl.start) / n
        loss, p = fn(sl)
        total += float(loss) * w
        for k, v in p.items():
            parts[k] = parts.get(k, 0.0) + float(v) * w
    return total, parts


def variance_floor_matrix(y_std: np.ndarray, floor: float) -> np.ndarray:
    """Symmetric ``W = V diag(sqrt(max(1, floor/lam))) V^T`` (n_out, n_out), with ``lam, V`` the
    eigenvalues and vectors of the covariance ``C`` of the standardized outputs ``y_std`` (N,
    n_out): ``W C W`` has the eigenvalues ``max(lam, floor)``. An error ``e`` (row) in standardized
    units is ``e @ W`` as the loss sees it: unchanged along directions of variance >= floor,
    scaled up along the smaller ones."""
    y = np.asarray(y_std, dtype=np.float64)
    lam, vec = np.linalg.eigh(np.cov(y, rowvar=False))
    if not np.all(lam > 0):
        raise ValueError(f"variance floor: the output covariance is singular (eigenvalue {lam.min():.3g})")
    return (vec * np.sqrt(np.maximum(1.0, float(floor) / lam))) @ vec.T


def relative_sample_weights(y_train: np.ndarray, y: np.ndarray, relative_weight: float) -> np.ndarray:
    """Row weights (N,) ``(1 - a) + a * (1/|y_i|^2) / mean_j(1/|y_train_j|^2)`` for the physical
    outputs ``y`` (N, n_out), ``|.|`` the Euclidean norm over the outputs and the mean over the
    rows of ``y_train``: they average 1 over ``y_train``; ``a = 0`` gives ones. Raises
    ``ValueError`` naming the first row whose norm is zero or not finite."""
    norms2 = {name: np.sum(np.asarray(a, np.float64) ** 2, axis=1) for name, a in (("training", y_train), ("given", y))}
    for name, n2 in norms2.items():
        bad = np.flatnonzero(~(np.isfinite(n2) & (n2 > 0)))
        if bad.size:
            raise ValueError(f"relative weights: row {bad[0]} of the {name} outputs has the squared norm {float(n2[bad[0]])!r}")
    a = float(relative_weight)
    return (1.0 - a) + a * (1.0 / norms2["given"]) / np.mean(1.0 / norms2["training"])


class EmulatorStage(_Stage):
    """MSE of ``NN_e`` on clean standardized data (no noise, no randomness besides shuffling);
    with ``weighting`` (a matrix W, :func:`variance_floor_matrix`) the MSE of ``(pred - y) @ W``;
    with ``row_weights`` (training, test: (N,) each, :func:`relative_sample_weights`) each row's
    squared errors times its weight. With either, the plain MSE is the part ``mse``."""

    name = "emulator"

    def __init__(self, model: nw.Emulator, v_tr, y_tr, v_te, y_te, device, dtype=torch.float32,
                 weighting: np.ndarray | None = None,
                 row_weights: tuple[np.ndarray, np.ndarray] | None = None):
        super().__init__(len(v_tr), device, dtype)
        self.model = model
        self.v_tr, self.y_tr = self.tensor(v_tr), self.tensor(y_tr)
        self.v_te, self.y_te = self.tensor(v_te), self.tensor(y_te)
        self.y_epoch = self.y_tr  # targets of the current epoch: always the clean data
        self.weighting = None if weighting is None else self.tensor(weighting)
        self.w_tr, self.w_te = (None, None) if row_weights is None else (self.tensor(row_weights[0])[:, None],
                                                                           self.tensor(row_weights[1])[:, None])
        self.parts = () if weighting is None and row_weights is None else ("mse",)

    def _loss(self, v, y, w=None):
        pred = self.model(v)
        if not self.parts:
            return nw.emulator_loss(pred, y), {}
        err = pred - y if self.weighting is None else (pred - y) @ self.weighting
        sq = err ** 2 if w is None else err ** 2 * w
        return torch.mean(sq), {"mse": nw.emulator_loss(pred.detach(), y)}

    def batch_loss(self, idx):
        return self._loss(self.v_tr[idx], self.y_epoch[idx], None if self.w_tr is None else self.w_tr[idx])

    @torch.no_grad()
    def evaluate(self):
        return _chunked_mean(len(self.v_te), lambda s: self._loss(
            self.v_te[s], self.y_te[s], None if self.w_te is None else self.w_te[s]))


class FlowStage(_Stage):
    """NLL of ``NN_f`` on noisy standardized outputs (fresh noise every epoch)."""

    name = "flow"

    def __init__(self, model: nw.RealNVP, y_tr, y_te, noise_level: float, test_generator, device,
                 dtype=torch.float32):
        super().__init__(len(y_tr), device, dtype)
        self.model, self.noise_level = model, float(noise_level)
        self.scale = model.y_scaler.std.detach().double().cpu()
        self.y_tr = self.tensor(y_tr)
        self.y_epoch = self.y_tr
        noise = _std_noise(len(y_te), self.noise_level, test_generator, self.scale)
        self.y_te = self.tensor(y_te if noise is None else torch.as_tensor(y_te) + noise)

    def begin_epoch(self, generator, epoch=0):
        noise = _std_noise(self.n_train, self.noise_level, generator, self.scale)
        self.y_epoch = self.y_tr if noise is None else self.y_tr + self.tensor(noise)

    def batch_loss(self, idx):
        return nw.flow_nll(self.model, self.y_epoch[idx]), {}

    @torch.no_grad()
    def evaluate(self):
        return _chunked_mean(len(self.y_te), lambda s: (nw.flow_nll(self.model, self.y_te[s]), {}))


class EncoderDecoderStage(_Stage):
    """Encoder/decoder loss with noisy y' as the decoder's input; the re-evaluation term
    compares the emulator's output with y' (``reeval_target`` "noisy") or with the clean y
    ("clean", as the paper's public code)."""

    name = "encoder_decoder"
    parts = ("decoder", "kl", "reeval")

    def __init__(self, model: nw.EncoderDecoder, emulator: nw.Emulator, v_tr, y_tr, v_te, y_te,
                 noise_level: float, hyper: dict, test_generator, device, dtype=torch.float32):
        super().__init__(len(v_tr), device, dtype)
        self.model, self.noise_level = model, float(noise_level)
        self.emulator = emulator
        self.reevaluate = nw.make_reevaluator(emulator, model)
        self.betas = (float(hyper["beta_d"]), float(hyper["beta_v"]), float(hyper["beta_r"]))
        self.kl_warmup = int(hyper["kl_warmup_epochs"])
        self.train_betas = self.betas
        self.reduction = hyper["reduction"]
        self.clean_target = hyper["reeval_target"] == "clean"
        self.latent = model.latent_dim
        self.scale = model.y_scaler.std.detach().double().cpu()
        self.v_tr, self.y_tr = self.tensor(v_tr), self.tensor(y_tr)
        self.v_te, self.y_te_clean = self.tensor(v_te), self.tensor(y_te)
        noise = _std_noise(len(y_te), self.noise_level, test_generator, self.scale)
        self.y_te = self.tensor(y_te if noise is None else torch.as_tensor(y_te) + noise)
        self.eps_te = self.tensor(torch.randn(len(v_te), self.latent, generator=test_generator))
        self.beta_prior = float(hyper["beta_prior"])
        if self.beta_prior > 0:  # no random numbers drawn otherwise: the paper's loss is unchanged
            self.parts = self.parts + ("prior_reeval",)
            self.w_prior_te = self.tensor(torch.randn(len(v_te), self.latent, generator=test_generator))
        else:
            self.w_prior_te = None
        self.y_epoch, self.eps_epoch, self.w_prior_epoch = self.y_tr, None, None

    def kl_factor(self, epoch: int) -> float:
        """Multiplier of ``beta_v`` in training epoch ``epoch`` (0-based): ``(epoch + 1) / k``
        during the first k = ``kl_warmup_epochs`` epochs, then 1."""
        return 1.0 if epoch >= self.kl_warmup else (epoch + 1) / self.kl_warmup

    def begin_epoch(self, generator, epoch=0):
        d, v, r = self.betas
        self.train_betas = (d, v * self.kl_factor(epoch), r)
        noise = _std_noise(self.n_train, self.noise_level, generator, self.scale)
        self.y_epoch = self.y_tr if noise is None else self.y_tr + self.tensor(noise)
        self.eps_epoch = self.tensor(torch.randn(self.n_train, self.latent, generator=generator))
        if self.beta_prior > 0:
            self.w_prior_epoch = self.tensor(torch.randn(self.n_train, self.latent, generator=generator))

    def _loss(self, v, y, eps, y_clean, betas, w_prior):
        return nw.encoder_decoder_loss(self.model, v, y, eps, self.reevaluate, *betas, reduction=self.reduction,
                                       y_target_std=y_clean if self.clean_target else None,
                                       w_prior=w_prior, beta_prior=self.beta_prior)

    def batch_loss(self, idx):
        w = None if self.w_prior_epoch is None else self.w_prior_epoch[idx]
        return self._loss(self.v_tr[idx], self.y_epoch[idx], self.eps_epoch[idx], self.y_tr[idx], self.train_betas, w)

    @torch.no_grad()
    def evaluate(self):
        w = self.w_prior_te
        return _chunked_mean(len(self.v_te), lambda s: self._loss(self.v_te[s], self.y_te[s], self.eps_te[s],
                                                                  self.y_te_clean[s], self.betas,
                                                                  None if w is None else w[s]))


# ----------------------------------------------------------------------------- outputs
def _columns(stage: _Stage, grad_clip: float = 0.0) -> list[str]:
    """Losses-CSV columns: ``skipped_steps`` last when the gradient guard is on."""
    cols = ["epoch", "train_loss", "test_loss", "lr", "seconds", "cpu_seconds"]
    cols += [f"train_{p}" for p in stage.parts] + [f"test_{p}" for p in stage.parts]
    return cols + (["skipped_steps"] if grad_clip > 0 else [])


def _write_rows(path: Path, columns: list[str], rows: list[dict], mode: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, mode, newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        if mode == "w":
            w.writeheader()
        for r in rows:  # a column the row lacks (a checkpoint of an older version) stays empty
            w.writerow({k: ("" if k not in r else int(r[k]) if k in ("epoch", "skipped_steps") else repr(float(r[k])))
                        for k in columns})


# ----------------------------------------------------------------------------- generic loop
def _read_checkpoint(path: Path) -> dict | None:
    """The checkpoint at ``path``, or None when there is none or it is unreadable (e.g.
    truncated: logged, and the run starts over)."""
    if not path.exists():
        return None
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        log.warning("ignoring unreadable checkpoint %s (%s)", path, exc)
        return None


def _save_checkpoint(path: Path, payload: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def _fit(stage: _Stage, hyper: dict, seed: int, fingerprint: str, model_path: str, losses: str,
         checkpoint: str | None, info: dict, max_epochs_this_run: int | None,
         checkpoint_every: int, progress: bool, max_cpu_seconds: float | None = None,
         until_epoch: int | None = None, extra: dict | None = None) -> dict:
    """Train ``stage.model`` (already seeded, built and on the device); see module docstring.
    ``max_cpu_seconds`` (benchmarks) stops after the epoch in which the run's CPU time, summed
    over epochs, reaches it (checkpoint only, as ``max_epochs_this_run``); ``until_epoch`` stops
    after that epoch of the schedule (restart candidates). ``extra`` (JSON-able dict) is kept in
    the checkpoint, restored from it on resume, and added to the saved model's ``info``."""
    from tqdm import tqdm

    device = stage.device
    model = stage.model
    params = [p for p in model.parameters() if p.requires_grad]
    opt = make_optimizer(params, float(hyper["lr"]), float(hyper["weight_decay"]), device)
    sched = make_scheduler(opt, hyper)
    eval_every, keep_best = int(hyper["eval_every"]), bool(hyper["keep_best"])
    best: dict = {"loss": math.inf, "epoch": 0, "model": None}
    gen = torch.Generator().manual_seed(derived_seed(seed, 1))
    epochs, bs = int(hyper["epochs"]), int(hyper["batch_size"])
    clip = float(hyper["grad_clip"])
    ckpt_path = Path(checkpoint) if checkpoint else Path(str(model_path) + ".ckpt")
    losses_path = Path(losses)
    columns = _columns(stage, clip)

    history: list[dict] = []
    start = 0
    ck = _read_checkpoint(ckpt_path)
    if ck is not None:
        if ck.get("fingerprint") == fingerprint:
            model.load_state_dict(ck["model"])
            opt.load_state_dict(ck["optimizer"])
            sched.load_state_dict(ck["scheduler"])
            gen.set_state(ck["generator"])
            torch.set_rng_state(ck["torch_rng"])
            history, start = list(ck["history"]), int(ck["epoch"])
            best = ck.get("best", best)
            extra = ck.get("extra") or extra
            log.info("%s: resuming from %s at epoch %d/%d", stage.name, ckpt_path, start, epochs)
        else:
            log.warning("%s: checkpoint %s is from a different run; starting over", stage.name, ckpt_path)
    _write_rows(losses_path, columns, history, "w")

    def save_ckpt(epoch: int, path: Path = ckpt_path) -> None:
        _save_checkpoint(path, {
            "fingerprint": fingerprint, "epoch": epoch, "model": model.state_dict(),
            "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "generator": gen.get_state(), "torch_rng": torch.get_rng_state(), "history": history,
            "best": best, "extra": extra or {},
        })

    stop = epochs if max_epochs_this_run is None else min(epochs, start + int(max_epochs_this_run))
    if until_epoch is not None:
        stop = min(stop, int(until_epoch))
    n = stage.n_train
    n_full = (n // bs) * bs
    bounds = [(b, min(n, b + bs)) for b in range(0, n, bs) if min(n, b + bs) - b >= 2 or b < n_full]
    bar = tqdm(total=epochs, initial=start, desc=stage.name, file=sys.stderr, disable=not progress,
               dynamic_ncols=True, mininterval=1.0)
    cpu_used = sum(r["cpu_seconds"] for r in history)
    for epoch in range(start, stop):
        t0, c0 = time.perf_counter(), time.process_time()
        model.train()
        stage.begin_epoch(gen, epoch)
        perm = torch.randperm(n, generator=gen).to(device)
        lr = opt.param_groups[0]["lr"]
        acc = torch.zeros((), device=device, dtype=torch.float64)
        acc_parts = {p: torch.zeros((), device=device, dtype=torch.float64) for p in stage.parts}
        used = skipped = 0
        for b0, b1 in bounds:
            idx = perm[b0:b1]
            loss, parts = stage.batch_loss(idx)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if clip > 0:
                norm = nn.utils.get_total_norm([p.grad for p in params if p.grad is not None])
                if not torch.isfinite(norm):  # overflowed (a loss spike): no update, out of the mean
                    skipped += 1
                    continue
                if norm > clip:  # else the gradient is left untouched, bit for bit
                    nn.utils.clip_grads_with_norm_(params, clip, norm)
            opt.step()
            k = b1 - b0
            acc += loss.detach().double() * k
            for p in stage.parts:
                acc_parts[p] += parts[p].double() * k
            used += k
        sched.step()
        model.eval()
        evaluated = (epoch + 1) % eval_every == 0 or epoch + 1 == epochs
        test_loss, test_parts = stage.evaluate() if evaluated else (math.nan, {})
        row = {"epoch": epoch + 1, "train_loss": float(acc) / used if used else math.nan, "test_loss": test_loss,
               "lr": lr}
        if clip > 0:
            row["skipped_steps"] = skipped
            if skipped:
                log.warning("%s: epoch %d: %d of %d steps skipped (non-finite gradient norm)", stage.name,
                            epoch + 1, skipped, len(bounds))
        for p in stage.parts:
            row[f"train_{p}"] = float(acc_parts[p]) / used if used else math.nan
            row[f"test_{p}"] = test_parts.get(p, math.nan)
        if keep_best and evaluated and test_loss < best["loss"]:
            best = {"loss": test_loss, "epoch": epoch + 1,
                    "model": {k: v.detach().clone() for k, v in model.state_dict().items()}}
        row["seconds"], row["cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
        cpu_used += row["cpu_seconds"]
        history.append(row)
        _write_rows(losses_path, columns, [row], "a")
        if not (math.isfinite(row["train_loss"]) and (math.isfinite(test_loss) or not evaluated)):
            bar.close()  # the last good checkpoint stays; the failed state is kept beside it
            failed = ckpt_path.with_name(ckpt_path.name + ".nonfinite")
            save_ckpt(epoch + 1, failed)
            raise FloatingPointError(f"{stage.name}: non-finite loss at epoch {epoch + 1} (its state: {failed}): {row}")
        bar.update(1)
        bar.set_postfix_str(f"train={row['train_loss']:.4g} test={test_loss:.4g} lr={lr:.3g}", refresh=False)
        if (epoch + 1) % checkpoint_every == 0 and epoch + 1 < stop:
            save_ckpt(epoch + 1)
        if max_cpu_seconds is not None and cpu_used >= max_cpu_seconds:
            break
    bar.close()
    done = len(history)
    save_ckpt(done)
    tested = [r for r in history if math.isfinite(r["test_loss"])]
    result = {"completed": done >= epochs, "epochs_done": done, "epochs_this_run": done - start,
              "cpu_seconds": cpu_used,
              "train_loss": history[-1]["train_loss"] if history else None,
              "test_loss": tested[-1]["test_loss"] if tested else None}
    if not result["completed"]:
        return result
    if keep_best and best["model"] is not None:
        model.load_state_dict(best["model"])
        result["test_loss"] = best["loss"]
    model.eval()
    info = {**info, **(extra or {}), "epochs_done": done, "final_train_loss": result["train_loss"],
            "final_test_loss": result["test_loss"], "best_epoch": best["epoch"] if keep_best else done,
            "device": str(device), "torch": str(torch.__version__)}
    nw.save_model(model, model_path, info=info)
    return result


def candidate_seed(seed: int, candidate: int) -> int:
    """Seed of restart candidate ``candidate`` (initial weights and training stream): ``seed``
    itself for candidate 0, so that a run with restarts in which candidate 0 wins continues
    exactly as the run without restarts; independent derived seeds for the others."""
    return int(seed) if candidate == 0 else derived_seed(seed, 1000 + int(candidate))


def _candidate_path(ckpt: Path, candidate: int) -> Path:
    return ckpt.with_name(f"{ckpt.name}.candidate{candidate}")


def _candidate_score(path: Path, fingerprint: str, restart_epochs: int) -> float | None:
    """Test loss of a finished restart candidate (its checkpoint at ``path``): the one at epoch
    ``restart_epochs``, ``inf`` for a candidate that diverged; ``None`` when it has still to (finish
    its) training. Reads only: a candidate trained by a job of its own is an input of the run."""
    ck = _read_checkpoint(path)
    if ck is None or ck.get("fingerprint") != fingerprint:
        return None
    if ck.get("diverged"):
        return math.inf
    if int(ck["epoch"]) < restart_epochs:
        return None
    return float(next(row["test_loss"] for row in ck["history"] if int(row["epoch"]) == restart_epochs))


def _run_candidate(make_stage: Callable[[int], _Stage], hyper: dict, seed: int, fingerprint: str, c: int,
                   path: Path, model_path: str, info: dict, max_epochs_this_run: int | None, checkpoint_every: int,
                   progress: bool, max_cpu_seconds: float | None) -> dict:
    """Train restart candidate ``c`` to epoch ``restart_epochs`` (or resume it), checkpoint at
    ``path``, losses at ``path + ".csv"``. Returns :func:`_fit`'s result with ``score`` (its test
    loss at the choice; ``inf`` when it diverged, recorded in its checkpoint so that no rerun
    replays it; ``None`` when stopped early by the budget)."""
    r = int(hyper["restart_epochs"])
    fp_c = f"{fingerprint}:candidate{c}"
    done = _candidate_score(path, fp_c, r)
    if done is not None:
        return {"completed": False, "epochs_done": r, "epochs_this_run": 0, "cpu_seconds": 0.0, "score": done}
    cseed = candidate_seed(seed, c)
    try:
        res = _fit(make_stage(cseed), hyper, cseed, fp_c, model_path, str(path) + ".csv", str(path), info,
                   max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds, until_epoch=r)
    except FloatingPointError as exc:  # a diverged candidate loses
        log.warning("%s: restart candidate %d diverged: %s", info.get("stage"), c, exc)
        _save_checkpoint(path, {"fingerprint": fp_c, "diverged": True, "error": str(exc)})
        return {"completed": False, "epochs_done": 0, "epochs_this_run": 0, "cpu_seconds": 0.0, "score": math.inf}
    score = float(res["test_loss"]) if res["epochs_done"] >= r else None  # evaluated at r (a multiple of eval_every)
    if score is not None:
        log.info("%s: restart candidate %d (seed %d): test loss %.6g at epoch %d", info.get("stage"), c, cseed,
                 score, r)
    return {**res, "score": score}


def _train(make_stage: Callable[[int], _Stage], hyper: dict, seed: int, fingerprint: str, model_path: str,
           losses: str, checkpoint: str | None, info: dict, max_epochs_this_run: int | None,
           checkpoint_every: int, progress: bool, max_cpu_seconds: float | None,
           candidate: int | None = None, candidates: list[str] | None = None) -> dict:
    """:func:`_fit` with best-of-``restarts`` initializations.

    ``make_stage(init_seed)`` builds the stage with a model seeded by ``torch.manual_seed(init_seed)``
    (everything else, test noise included, from the master ``seed``). With ``restarts`` k > 1, k
    candidates (seeds :func:`candidate_seed`) each train the first ``restart_epochs`` epochs of the
    full schedule, exactly as they would alone, with their own checkpoint and losses CSV
    (``candidates[c]`` and ``candidates[c] + ".csv"``; by default ``<checkpoint>.candidate<c>``);
    the one with the lowest test loss at that epoch (the criterion of ``keep_best``; ties to the
    lower index; a diverged one loses) becomes the run's checkpoint and trains to the end. Every
    phase resumes from its checkpoint; ``max_epochs_this_run`` and ``max_cpu_seconds`` count
    across the candidates. The model's ``info`` gets ``restart``: the candidates' seeds and test
    losses and the chosen index.

    ``candidate`` = c trains only candidate c, to the choice, at ``checkpoint`` (required) with its
    losses at ``losses`` (the workflow runs each candidate as a job of its own, side by side, and
    gives the run their checkpoints as ``candidates``: finished ones are read, not retrained).
    """
    k = int(hyper["restarts"])
    if candidate is not None:
        if k == 1 or not (int(candidate) == candidate and 0 <= candidate < k):
            raise ValueError(f"{info.get('stage')}: restart candidate {candidate!r} is not one of the {k} "
                             f"initializations (restarts: {k})")
        if not checkpoint or Path(losses) != Path(str(checkpoint) + ".csv"):
            raise ValueError(f"restart candidate {candidate}: give its checkpoint, with losses at checkpoint + '.csv' "
                             f"(got checkpoint={checkpoint!r}, losses={losses!r})")
        return _run_candidate(make_stage, hyper, seed, fingerprint, int(candidate), Path(checkpoint), model_path,
                              info, max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds)
    if k == 1:
        return _fit(make_stage(seed), hyper, seed, fingerprint, model_path, losses, checkpoint, info,
                    max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds)
    ckpt = Path(checkpoint) if checkpoint else Path(str(model_path) + ".ckpt")
    paths = [Path(x) for x in candidates] if candidates else [_candidate_path(ckpt, c) for c in range(k)]
    if len(paths) != k:
        raise ValueError(f"{info.get('stage')}: {len(paths)} candidate checkpoints given for restarts: {k}")
    r = int(hyper["restart_epochs"])
    budget, cpu_left = max_epochs_this_run, max_cpu_seconds
    if (_read_checkpoint(ckpt) or {}).get("fingerprint") != fingerprint:
        scores: list[float] = []
        for c, path in enumerate(paths):
            res = _run_candidate(make_stage, hyper, seed, fingerprint, c, path, model_path, info, budget,
                                 checkpoint_every, progress, cpu_left)
            if budget is not None:
                budget -= res["epochs_this_run"]
            if cpu_left is not None:
                cpu_left -= res["cpu_seconds"]
            if res["score"] is None:  # stopped by the budget: resume later
                return {**res, "completed": False}
            scores.append(res["score"])
        if not any(math.isfinite(x) for x in scores):
            raise FloatingPointError(f"{info.get('stage')}: all {k} restart candidates diverged")
        chosen = int(np.argmin(scores))
        log.info("%s: candidate %d chosen of %d", info.get("stage"), chosen, k)
        ck = torch.load(paths[chosen], map_location="cpu", weights_only=True)
        ck["fingerprint"] = fingerprint
        ck["extra"] = {"restart": {"epochs": r, "chosen": chosen,
                                   "seeds": [candidate_seed(seed, c) for c in range(k)], "test_loss": scores}}
        _save_checkpoint(ckpt, ck)
    # the run's checkpoint holds the chosen candidate: _fit resumes it (its weights and streams)
    return _fit(make_stage(seed), hyper, seed, fingerprint, model_path, losses, checkpoint, info,
                budget, checkpoint_every, progress, cpu_left)


def _setup(stage: str, hyper: dict, device: str, threads: int) -> tuple[dict, torch.device, torch.dtype]:
    h = check_hyper(stage, hyper)
    torch.set_num_threads(int(threads))
    return h, resolve_device(device), _DTYPES[h["dtype"]]


def inflate_output_scale(scaler: nw.Standardizer, noise_level: float) -> None:
    """Widen a fitted output standardizer to the std of the *noisy* outputs,
    ``sqrt(std^2 + (delta * s)^2)`` per output (s: registry noise std, clinical units), as the
    paper's public code standardizes in its noisy studies. No change when ``noise_level`` is 0."""
    if noise_level == 0:
        return
    s = torch.as_tensor(noise_std(), dtype=torch.float64) * float(noise_level)
    with torch.no_grad():
        scaler.std.copy_(torch.sqrt(scaler.std.double() ** 2 + s ** 2).to(scaler.std))


#: The layers training code may import: every source file under them enters the digest.
_DIGEST_LAYERS = ("__init__.py", "registry.py", "model", "data", "nets", "training")


def training_code_digest() -> str:
    """sha256 over the source of the training subpackage and of the layers below it
    (:data:`_DIGEST_LAYERS`): a superset of the files the workflow's training rules declare
    as their ``code`` input, so a code change that reruns a training rule also retires its
    checkpoints."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(f for layer in _DIGEST_LAYERS for f in
                   ([root / layer] if layer.endswith(".py") else (root / layer).rglob("*.py")))
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _fingerprint(**items) -> str:
    """Identity of a training run, kept in its checkpoints: the given items plus the training
    code's digest, so a checkpoint (finished ones included) is reused only by the code that
    wrote it and a rule rerun after a code change retrains instead of re-saving old weights."""
    items = {**items, "code": training_code_digest()}
    return hashlib.sha256(json.dumps(items, sort_keys=True, default=str).encode()).hexdigest()


# ----------------------------------------------------------------------------- entry points
def positive_columns(v: np.ndarray) -> list[int]:
    """Indices of the columns of ``v`` (N, n) whose values are all > 0: the parameters the
    ``log_inputs`` / ``log_parameters`` options take logarithms of (in CVSim-6 all but P_th)."""
    return [j for j in range(v.shape[1]) if v[:, j].min() > 0]


def train_emulator(train: str, test: str, model: str, losses: str, hyper: dict, seed: int,
                   device: str = "auto", threads: int = 1, checkpoint: str | None = None,
                   max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                   progress: bool = True, max_cpu_seconds: float | None = None,
                   candidate: int | None = None, candidates: list[str] | None = None) -> dict:
    """Train ``NN_e`` (parameters -> outputs) on clean data; write ``model`` (.pt) and ``losses``
    (CSV, one row per epoch; :func:`cvsim6.reporting.loss_figures.plot_training_losses` draws it).
    ``max_epochs_this_run`` stops early after that many epochs of this call (checkpoint only,
    no model written). With ``restarts``: ``candidate`` trains that initialization only, to the
    choice, at ``checkpoint`` (``losses`` = checkpoint + ".csv"; no model written), and
    ``candidates`` names the candidates' checkpoints (see :func:`_train`). Returns a summary dict
    (``completed``, ``epochs_done``, ``train_loss``, ``test_loss``; a candidate's ``score``)."""
    h, dev, dtype = _setup("emulator", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)

    log_cols = positive_columns(v_tr) if h["log_inputs"] else []

    def make_stage(init_seed: int) -> EmulatorStage:
        torch.manual_seed(init_seed)
        net = nw.Emulator(h["hidden"], h["layers"], activation=h["activation"], linear_skip=h["linear_skip"],
                          log_inputs=log_cols)
        net.x_scaler.fit(v_tr)
        net.fit_features(v_tr)
        net.y_scaler.fit(y_tr)
        net.to(dev, dtype)
        y_tr_std = net.y_scaler.transform(y_tr)
        weighting = None if h["variance_floor"] is None else variance_floor_matrix(y_tr_std, h["variance_floor"])
        a = h["relative_weight"]
        rows = None if a == 0 else (relative_sample_weights(y_tr, y_tr, a), relative_sample_weights(y_tr, y_te, a))
        return EmulatorStage(net, net.x_scaler.transform(v_tr), y_tr_std,
                             net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), dev, dtype, weighting, rows)

    fp = _fingerprint(stage="emulator", hyper=h, seed=seed, data=_digest(v_tr, y_tr, v_te, y_te), fmt=nw.FORMAT)
    info = {"stage": "emulator", "hyper": h, "seed": seed, "noise_level": 0.0, "n_train": len(v_tr), "n_test": len(v_te)}
    return _train(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)


def train_flow(train: str, test: str, model: str, losses: str, hyper: dict, seed: int,
               noise_level: float = 0.0, device: str = "auto", threads: int = 1, checkpoint: str | None = None,
               max_epochs_this_run: int | None = None, checkpoint_every: int = 50, progress: bool = True,
               max_cpu_seconds: float | None = None, candidate: int | None = None,
               candidates: list[str] | None = None) -> dict:
    """Train the Real-NVP ``NN_f`` on the outputs with training noise of level ``noise_level``
    (delta, multiplier of the registry noise std). Outputs and return value as
    :func:`train_emulator`."""
    h, dev, dtype = _setup("flow", hyper, device, threads)
    _, y_tr = load_split(train)
    _, y_te = load_split(test)

    def make_stage(init_seed: int) -> FlowStage:
        torch.manual_seed(init_seed)
        net = nw.RealNVP(hidden=h["hidden"], blocks=h["blocks"], layers_per_block=h["layers_per_block"],
                         batchnorm=bool(h["batchnorm"]))
        net.y_scaler.fit(y_tr)
        if h["noisy_scaling"]:
            inflate_output_scale(net.y_scaler, noise_level)
        net.to(dev, dtype)
        test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
        return FlowStage(net, net.y_scaler.transform(y_tr), net.y_scaler.transform(y_te), noise_level, test_gen,
                         dev, dtype)

    fp = _fingerprint(stage="flow", hyper=h, seed=seed, noise=float(noise_level), data=_digest(y_tr, y_te),
                      noise_std=noise_std().tolist(), fmt=nw.FORMAT)
    info = {"stage": "flow", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(y_tr), "n_test": len(y_te), "label": f"delta={noise_level:g}"}
    return _train(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)


def train_encoder_decoder(train: str, test: str, emulator: str, model: str, losses: str,
                          hyper: dict, seed: int, noise_level: float = 0.0, device: str = "auto",
                          threads: int = 1, checkpoint: str | None = None,
                          max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                          progress: bool = True, max_cpu_seconds: float | None = None,
                          candidate: int | None = None, candidates: list[str] | None = None) -> dict:
    """Train ``NN_v`` + ``NN_d`` with the re-evaluation term through the frozen emulator file
    ``emulator``; training noise of level ``noise_level`` on y' everywhere. Outputs and return
    value as :func:`train_emulator`."""
    h, dev, dtype = _setup("encoder_decoder", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)
    emu = nw.load_model(emulator, map_location=dev)
    if not isinstance(emu, nw.Emulator):
        raise ValueError(f"{emulator}: expected an emulator model, got {type(emu).__name__}")
    emu.to(dtype=dtype).eval().requires_grad_(False)
    log_cols = positive_columns(v_tr) if h["log_parameters"] else []

    def make_stage(init_seed: int) -> EncoderDecoderStage:
        torch.manual_seed(init_seed)
        net = nw.EncoderDecoder(latent_dim=h["latent_dim"], encoder_hidden=h["encoder_hidden"],
                                encoder_layers=h["encoder_layers"], decoder_hidden=h["decoder_hidden"],
                                decoder_layers=h["decoder_layers"], activation=h["activation"],
                                logvar_max=h["logvar_max"], log_params=log_cols)
        net.x_scaler.fit(v_tr)
        net.y_scaler.fit(y_tr)
        if h["noisy_scaling"]:
            inflate_output_scale(net.y_scaler, noise_level)
        net.to(dev, dtype)
        test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
        return EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                                   net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), noise_level, h,
                                   test_gen, dev, dtype)

    fp = _fingerprint(stage="encoder_decoder", hyper=h, seed=seed, noise=float(noise_level),
                      data=_digest(v_tr, y_tr, v_te, y_te), emulator=_file_digest(emulator),
                      noise_std=noise_std().tolist(), fmt=nw.FORMAT)
    info = {"stage": "encoder_decoder", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(v_tr), "n_test": len(v_te), "label": f"delta={noise_level:g}"}
    return _train(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)
