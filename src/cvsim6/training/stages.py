"""The three training stages: what the epoch loop (:mod:`cvsim6.training.loop`) needs from each.

A stage holds its model and data on the device (standardized, float tensors) and gives the
loss of a minibatch (train mode) and of the whole test split (eval mode, in chunks).

Noise (flow, encoder/decoder, re-evaluation term; delta = ``noise_level``): once per epoch a
fresh draw ``eta ~ N(0, diag((delta*s)^2))`` in physical units (s: registry noise std) for the
whole training set, added to y and then standardized (``y_std + eta / std_y``); never for the
emulator. Per epoch and in this order the stage draws from the run's generator the noise, the
reparameterization ``eps`` (encoder/decoder) and, with ``beta_prior``, the prior draws ``w``;
the test split gets one fixed draw of each from a second generator.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from cvsim6 import nets as nw

#: Test rows per evaluation chunk (bounds the memory of an evaluation).
EVAL_CHUNK = 65536


def _to_device(a: np.ndarray | torch.Tensor, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``a`` as a tensor of ``dtype`` on ``device``."""
    return torch.as_tensor(a).to(dtype=dtype).to(device)


def _std_noise(n: int, noise_level: float, generator: torch.Generator, y_std_scale: torch.Tensor) -> torch.Tensor | None:
    """Per-sample noise in standardized units, (n, 16) float64 CPU, or None when delta == 0."""
    if noise_level == 0:
        return None
    return nw.draw_noise(n, noise_level, generator) / y_std_scale


class Stage:
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
    """Row-weighted mean of ``fn(rows)`` (a loss and its parts) over ``n`` rows, taken in chunks
    of :data:`EVAL_CHUNK` rows."""
    total, parts = 0.0, {}
    for start in range(0, n, EVAL_CHUNK):
        sl = slice(start, min(n, start + EVAL_CHUNK))
        w = (sl.stop - sl.start) / n
        loss, p = fn(sl)
        total += float(loss) * w
        for k, v in p.items():
            parts[k] = parts.get(k, 0.0) + float(v) * w
    return total, parts


class EmulatorStage(Stage):
    """MSE of ``NN_e`` on clean standardized data (no noise, no randomness besides shuffling);
    with ``weighting`` (a matrix W, :func:`~cvsim6.training.loss_weights.variance_floor_matrix`)
    the MSE of ``(pred - y) @ W``; with ``row_weights`` (training, test: (N,) each,
    :func:`~cvsim6.training.loss_weights.relative_sample_weights`) each row's squared errors
    times its weight. With either, the plain MSE is the part ``mse``."""

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


class FlowStage(Stage):
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


class EncoderDecoderStage(Stage):
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
    def reconstruction_errors(self) -> torch.Tensor:
        """Per parameter (23,), the decoder's mean squared error of the standardized test
        parameters given the test outputs (noisy as in :meth:`evaluate`) and w = the encoder's
        mean: near 0 for every parameter once the encoder has found every direction the outputs
        leave open, about the parameter's unexplained variance for one it has not."""
        err = torch.zeros(self.v_te.shape[1], dtype=torch.float64)
        for s in range(0, len(self.v_te), EVAL_CHUNK):
            v, y = self.v_te[s:s + EVAL_CHUNK], self.y_te[s:s + EVAL_CHUNK]
            err += ((self.model.decode(y, self.model.encode(v)[0]) - v) ** 2).sum(0).double().cpu()
        return err / len(self.v_te)

    @torch.no_grad()
    def evaluate(self):
        w = self.w_prior_te
        return _chunked_mean(len(self.v_te), lambda s: self._loss(self.v_te[s], self.y_te[s], self.eps_te[s],
                                                                  self.y_te_clean[s], self.betas,
                                                                  None if w is None else w[s]))
