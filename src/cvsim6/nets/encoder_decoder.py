"""The encoder ``NN_v`` and decoder ``NN_d``, their loss and the training noise.

Encoder MLP 23 -> 2*19 (mean, log-variance of the latent ``w``), decoder MLP (16 + 19) -> 23,
SiLU. :func:`encoder_decoder_loss` implements the paper's equation with sums over samples
replaced by means over the minibatch.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from cvsim6.nets.emulator import Emulator
from cvsim6.nets.layers import MLP, LogStandardizer, Standardizer, as_model_tensor
from cvsim6.registry import N_OUTPUTS, N_PARAMETERS
from cvsim6.registry import noise_std as _noise_std

#: Predictor-corrector rounds when decoding (:meth:`EncoderDecoder.invert`): the paper's
#: code uses 2. The one default of the library, the CLI and the workflow's functions.
DEFAULT_CORRECTOR_STEPS = 2


class EncoderDecoder(nn.Module):
    """``NN_v`` (encoder) and ``NN_d`` (decoder).

    Encoder: standardized v (N, 23) -> [mu (N, latent), log sigma^2 (N, latent)] (first half
    mean, second half log-variance). Decoder: [y_std (N, 16), w (N, latent)] -> v_std (N, 23).
    Defaults (paper): encoder 32 x 6 = 6,246, decoder 64 x 6 = 20,439 parameters, latent 19.

    ``log_params`` (column indices; default none, the paper's): the model sees and decodes those
    parameters as standardized logarithms (:class:`LogStandardizer`), so every decoded set is
    positive there, however far the decoder extrapolates; the others are standardized as they are.

    ``logvar_max`` (None: unbounded, the paper's): the log-variance's value is capped there
    (sigma^2 <= exp(logvar_max) in the standardized latent space, whose prior has sigma^2 = 1),
    its gradient passed straight through, so one sample's log-variance that an update throws far
    up is pulled back down by a finite KL gradient instead of overflowing it. Below the cap the
    value and gradient are the unbounded ones, bit for bit.
    """

    kind = "encoder_decoder"

    def __init__(self, n_params: int = N_PARAMETERS, n_outputs: int = N_OUTPUTS, latent_dim: int = 19,
                 encoder_hidden: int = 32, encoder_layers: int = 6, decoder_hidden: int = 64,
                 decoder_layers: int = 6, activation: str = "silu", logvar_max: float | None = None,
                 log_params: list[int] | tuple[int, ...] = ()):
        super().__init__()
        self.config = dict(n_params=int(n_params), n_outputs=int(n_outputs), latent_dim=int(latent_dim),
                           encoder_hidden=int(encoder_hidden), encoder_layers=int(encoder_layers),
                           decoder_hidden=int(decoder_hidden), decoder_layers=int(decoder_layers),
                           activation=str(activation))
        if logvar_max is not None:  # absent from the config of an unbounded model (the published ones)
            self.config["logvar_max"] = float(logvar_max)
        self.logvar_max = self.config.get("logvar_max")
        self.latent_dim = int(latent_dim)
        self.encoder = MLP(n_params, 2 * latent_dim, encoder_hidden, encoder_layers, activation)
        self.decoder = MLP(n_outputs + latent_dim, n_params, decoder_hidden, decoder_layers, activation)
        log_params = sorted({int(i) for i in log_params})
        if log_params:  # absent from the config of a model without (the published ones)
            self.config["log_params"] = log_params
        self.x_scaler = LogStandardizer(n_params, log_params) if log_params else Standardizer(n_params)
        self.y_scaler = Standardizer(n_outputs)

    def encode(self, v_std: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(mu, logvar)``, each (N, latent); logvar capped at ``logvar_max`` (class docstring)."""
        h = self.encoder(v_std)
        mu, logvar = h[:, : self.latent_dim], h[:, self.latent_dim:]
        if self.logvar_max is not None:
            logvar = logvar - (logvar - logvar.clamp(max=self.logvar_max)).detach()
        return mu, logvar

    def decode(self, y_std: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Standardized parameters (N, 23) from standardized outputs and latent w."""
        return self.decoder(torch.cat((y_std, w), dim=1))

    @staticmethod
    def latent_sample(mu: torch.Tensor, logvar: torch.Tensor, eps: torch.Tensor | None) -> torch.Tensor:
        """``w = mu + eps * sigma`` (reparameterization; ``w = mu`` if eps is None)."""
        return mu if eps is None else mu + eps * torch.exp(0.5 * logvar)

    def forward(self, v_std: torch.Tensor, y_std: torch.Tensor, eps: torch.Tensor | None = None):
        """``(v_hat_std, mu, logvar)`` with ``w = mu + eps * sigma`` (``w = mu`` if eps is None)."""
        mu, logvar = self.encode(v_std)
        return self.decode(y_std, self.latent_sample(mu, logvar, eps)), mu, logvar

    @torch.no_grad()
    def invert(self, y, w, corrector_steps: int = DEFAULT_CORRECTOR_STEPS):
        """Physical outputs (N, 16) and latent w (N, latent) -> physical parameters (N, 23).

        ``corrector_steps`` rounds of predictor-corrector sampling (inVAErt, Tong et al. 2024,
        section 3.3; the paper's code uses 2): the decoded v goes back through NN_v and its
        mean ``mu(v)`` replaces w before decoding again, pulling draws from the N(0, I) tails
        into the region the encoder maps data to.
        """
        if corrector_steps < 0:
            raise ValueError(f"corrector_steps must be >= 0, got {corrector_steps}")
        t, was_numpy = as_model_tensor(self, y)
        wt, _ = as_model_tensor(self, w)
        was_training = self.training
        self.eval()
        y_std = self.y_scaler.transform(t)
        v_std = self.decode(y_std, wt)
        for _ in range(int(corrector_steps)):
            v_std = self.decode(y_std, self.encode(v_std)[0])
        v = self.x_scaler.inverse(v_std)
        self.train(was_training)
        return v.double().cpu().numpy() if was_numpy else v


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """``1/2 sum_k (mu^2 + sigma^2 - log sigma^2 - 1)`` per sample, mean over the batch."""
    return 0.5 * (mu * mu + torch.exp(logvar) - logvar - 1.0).sum(dim=1).mean()


def squared_error(a: torch.Tensor, b: torch.Tensor, reduction: str = "sum") -> torch.Tensor:
    """Reduced squared error. ``"sum"``: ``||a - b||^2`` per sample, mean over the batch (the
    paper's equation with the sum over samples replaced by a mean); ``"mse"``: mean over batch
    *and* components (``nn.MSELoss``, as in the paper's public code)."""
    d = (a - b) ** 2
    if reduction == "sum":
        return d.sum(dim=1).mean()
    if reduction == "mse":
        return d.mean()
    raise ValueError(f"reduction must be 'sum' or 'mse', got {reduction!r}")


def encoder_decoder_loss(model: EncoderDecoder, v_std: torch.Tensor, y_std: torch.Tensor,
                         eps: torch.Tensor, reevaluate: Callable[[torch.Tensor], torch.Tensor] | None,
                         beta_d: float, beta_v: float, beta_r: float, reduction: str = "sum",
                         y_target_std: torch.Tensor | None = None, w_prior: torch.Tensor | None = None,
                         beta_prior: float = 0.0):
    """Encoder/decoder loss of the paper, means over the minibatch.

    ``beta_d * E||v - NN_d(y', w)||^2 + beta_v * E[1/2 sum_k(mu^2 + sigma^2 - log sigma^2 - 1)]
    + beta_r * E||y' - NN_e(NN_d(y', w))||^2`` with ``w = mu + eps * sigma``. ``y_std`` is the
    (noisy) standardized y'; ``y_target_std`` replaces y' as the re-evaluation target when
    given (the clean y, as in the paper's public code); ``eps`` (N, latent) standard normal; ``reevaluate`` maps decoded
    standardized v to standardized y through the frozen emulator (None or beta_r == 0 skips it).
    ``reduction`` applies to the squared-error terms (see :func:`squared_error`); the KL
    term is always summed over latent dimensions.

    Not in the paper: with ``w_prior`` (N, latent; draws from the prior N(0, I), the latent
    draws an inversion decodes) and ``beta_prior`` > 0, ``+ beta_prior * E||y' -
    NN_e(NN_d(y', w_prior))||^2`` (same target as the re-evaluation term). Both halves are
    decoded and re-evaluated as one batch of 2N rows.

    Returns ``(total, parts)`` where ``parts`` has the unweighted ``decoder``, ``kl`` and
    ``reeval`` terms, and ``prior_reeval`` when that term is on (detached tensors).
    """
    n = len(v_std)
    prior = w_prior is not None and beta_prior != 0 and reevaluate is not None
    mu, logvar = model.encode(v_std)
    w = model.latent_sample(mu, logvar, eps)
    if prior:
        decoded = model.decode(torch.cat((y_std, y_std)), torch.cat((w, w_prior.to(w))))
    else:
        decoded = model.decode(y_std, w)
    dec = squared_error(decoded[:n], v_std, reduction)
    kl = kl_divergence(mu, logvar)
    total = beta_d * dec + beta_v * kl
    parts = {"decoder": dec.detach(), "kl": kl.detach()}
    if prior or (reevaluate is not None and beta_r != 0):
        target = y_std if y_target_std is None else y_target_std
        y_hat = reevaluate(decoded)
        rec = squared_error(y_hat[:n], target, reduction)
        total = total + beta_r * rec
        if prior:
            rec_prior = squared_error(y_hat[n:], target, reduction)
            total = total + beta_prior * rec_prior
            parts["prior_reeval"] = rec_prior.detach()
    else:
        rec = torch.zeros((), device=v_std.device, dtype=v_std.dtype)
    parts["reeval"] = rec.detach()
    return total, parts


def make_reevaluator(emulator: Emulator, model: EncoderDecoder) -> Callable[[torch.Tensor], torch.Tensor]:
    """``v_std`` (model's x scaling) -> emulator prediction in the model's y scaling.

    Converts between the two models' standardizations with exact affine maps (identity when
    both were fitted on the same training data); through physical units when the model
    standardizes logarithms (``log_params``). The emulator is not modified; freeze it
    (``requires_grad_(False)``, ``eval()``) before training.
    """
    log_params = isinstance(model.x_scaler, LogStandardizer)
    with torch.no_grad():
        ya = emulator.y_scaler.std.to(model.y_scaler.std) / model.y_scaler.std
        yb = (emulator.y_scaler.mean.to(model.y_scaler.mean) - model.y_scaler.mean) / model.y_scaler.std
        if not log_params:
            xa = model.x_scaler.std / emulator.x_scaler.std.to(model.x_scaler.std)
            xb = (model.x_scaler.mean - emulator.x_scaler.mean.to(model.x_scaler.mean)) / emulator.x_scaler.std.to(model.x_scaler.std)
        identity = not log_params and bool(torch.all(xa == 1) and torch.all(xb == 0) and torch.all(ya == 1)
                                           and torch.all(yb == 0))

    def reevaluate(v_std: torch.Tensor) -> torch.Tensor:
        if identity:
            return emulator(v_std)
        if log_params:
            u = emulator.x_scaler.transform(model.x_scaler.inverse(v_std))
        else:
            u = v_std * xa.to(v_std) + xb.to(v_std)
        return emulator(u) * ya.to(v_std) + yb.to(v_std)

    return reevaluate


# ----------------------------------------------------------------------------- noise
def draw_noise(n: int, noise_level: float, generator: torch.Generator | None = None,
               std: np.ndarray | None = None, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Measurement noise ``eta ~ N(0, diag((delta * s)^2))`` in physical units, (n, 16), CPU.

    ``s`` defaults to :func:`cvsim6.registry.noise_std`. ``noise_level`` (delta) 0 returns
    zeros without consuming random numbers.
    """
    s = np.asarray(_noise_std() if std is None else std, dtype=np.float64)
    if noise_level == 0:
        return torch.zeros(n, s.size, dtype=dtype)
    eps = torch.randn(n, s.size, generator=generator, dtype=dtype)
    return eps * torch.as_tensor(noise_level * s, dtype=dtype)
