"""InVAErt networks for CVSim-6: emulator, Real-NVP density estimator, encoder/decoder.

Shapes and spaces
-----------------
* ``v``: model parameters, (N, 23), registry order; ``y``: clinical outputs, (N, 16).
* Every network works in *standardized* space (training-set mean/std, see
  :class:`Standardizer`); each model carries its own ``x_scaler``/``y_scaler`` buffers, so a
  saved model file is self-contained. Methods named ``*_physical``/``predict``/``invert``
  take and return physical (clinical) units.

Components (paper section 2.2, appendix B)
------------------------------------------
* :class:`Emulator` ``NN_e``: MLP 23 -> 16, SiLU (hidden 60 x 8 layers = 24,376 parameters;
  hidden 80 = 42,096); optionally plus a linear map of the inputs (``linear_skip``, 384
  parameters more; not in the paper).
* :class:`RealNVP` ``NN_f``: affine coupling flow on the 16 outputs. Direction convention:
  ``forward`` maps **data -> latent** (y -> z) and returns ``log|det dz/dy|``; ``inverse``
  maps latent -> data and returns ``log|det dy/dz|``. ``log_prob(y) = log N(z; 0, I) +
  log|det dz/dy|``, identical to the paper's ``log pi_0(z^(0)) - sum_l log|det dz^(l)/dz^(l-1)|``
  whose layers run latent -> data.
* :class:`EncoderDecoder` ``NN_v`` + ``NN_d``: encoder MLP 23 -> 2*19 (mean, log-variance of
  ``w``), decoder MLP (16 + 19) -> 23, SiLU.

Losses (:func:`emulator_loss`, :func:`flow_nll`, :func:`encoder_decoder_loss`) implement the
paper's equation with sums over samples replaced by means over the minibatch.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cvsim6.registry import N_OUTPUTS, N_PARAMETERS
from cvsim6.registry import noise_std as _noise_std

#: Version tag stored in every saved model file.
FORMAT = "cvsim6-invaert/1"
#: Predictor-corrector rounds when decoding (:meth:`EncoderDecoder.invert`): the paper's
#: code uses 2. The one default of the library, the CLI and the workflow's functions.
DEFAULT_CORRECTOR_STEPS = 2

_ACTIVATIONS: dict[str, type[nn.Module]] = {
    "silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU, "gelu": nn.GELU, "elu": nn.ELU,
}


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters of ``module`` (buffers such as scalers excluded)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def _activation(activation: str | type[nn.Module] | Callable[[], nn.Module]) -> Callable[[], nn.Module]:
    if isinstance(activation, str):
        try:
            return _ACTIVATIONS[activation.lower()]
        except KeyError:
            raise ValueError(f"unknown activation {activation!r}; one of {sorted(_ACTIVATIONS)}") from None
    return activation


class MLP(nn.Sequential):
    """Fully connected network with ``n_layers`` Linear layers in total.

    ``Linear(n_in, hidden), act, [Linear(hidden, hidden), act] * (n_layers - 2),
    Linear(hidden, n_out)``; no activation after the last layer. ``activation`` is a name
    ("silu", "tanh", "relu", ...) or a module class/factory.
    """

    def __init__(self, n_in: int, n_out: int, hidden: int, n_layers: int,
                 activation: str | type[nn.Module] | Callable[[], nn.Module] = nn.SiLU):
        if n_layers < 1:
            raise ValueError("n_layers must be >= 1")
        act = _activation(activation)
        if n_layers == 1:
            layers: list[nn.Module] = [nn.Linear(n_in, n_out)]
        else:
            layers = [nn.Linear(n_in, hidden), act()]
            for _ in range(n_layers - 2):
                layers += [nn.Linear(hidden, hidden), act()]
            layers.append(nn.Linear(hidden, n_out))
        super().__init__(*layers)


class Standardizer(nn.Module):
    """Affine standardization ``(x - mean) / std`` with mean/std stored as buffers.

    Columns with zero (or non-finite) std get std 1. ``transform``/``inverse`` accept numpy
    arrays (returned as float64 numpy) or tensors (computed in the tensor's dtype/device).
    """

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @torch.no_grad()
    def fit(self, data: np.ndarray | torch.Tensor) -> "Standardizer":
        """Set mean and (population) std from ``data`` (N, dim); returns self."""
        x = np.asarray(data.detach().cpu() if isinstance(data, torch.Tensor) else data, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.mean.numel():
            raise ValueError(f"expected (N, {self.mean.numel()}) data, got {x.shape}")
        mean, std = x.mean(axis=0), x.std(axis=0)
        std = np.where(np.isfinite(std) & (std > 0), std, 1.0)
        self.mean.copy_(torch.as_tensor(mean))
        self.std.copy_(torch.as_tensor(std))
        return self

    def transform(self, x):
        """Physical -> standardized."""
        if isinstance(x, torch.Tensor):
            return (x - self.mean.to(x)) / self.std.to(x)
        return (np.asarray(x, dtype=np.float64) - self.mean.double().cpu().numpy()) / self.std.double().cpu().numpy()

    def inverse(self, x):
        """Standardized -> physical."""
        if isinstance(x, torch.Tensor):
            return x * self.std.to(x) + self.mean.to(x)
        return np.asarray(x, dtype=np.float64) * self.std.double().cpu().numpy() + self.mean.double().cpu().numpy()


class LogStandardizer(Standardizer):
    """Standardization of ``log x`` in the columns ``log_columns`` and of ``x`` in the others.

    ``transform`` maps physical values to the standardized features, ``inverse`` back (``exp``
    in the log columns), so a network whose outputs are read through ``inverse`` can only give
    positive values there. ``fit`` and ``transform`` raise ``ValueError`` naming a log column
    with a value <= 0 (its logarithm is undefined). Same numpy/tensor handling as
    :class:`Standardizer`.
    """

    def __init__(self, dim: int, log_columns: list[int] | tuple[int, ...]):
        super().__init__(dim)
        cols = sorted({int(i) for i in log_columns})
        if not cols or any(not 0 <= i < dim for i in cols):
            raise ValueError(f"log_columns must be non-empty column indices in [0, {dim}), got {list(log_columns)}")
        mask = torch.zeros(dim, dtype=torch.bool)
        mask[cols] = True
        self.register_buffer("log_mask", mask)

    def _check_positive(self, x) -> None:
        m = self.log_mask.cpu().numpy()
        vals = np.asarray(x.detach().cpu() if isinstance(x, torch.Tensor) else x, dtype=np.float64)
        vals = vals.reshape(-1, m.size)[:, m]
        bad = ~(vals > 0)  # NaN is bad too
        if bad.any():
            k = int(np.argmax(bad.any(axis=0)))
            raise ValueError(f"column {int(np.flatnonzero(m)[k])} is standardized as a logarithm but has "
                             f"a value <= 0 or NaN ({vals[bad[:, k], k][0]!r})")

    def _log(self, x):
        self._check_positive(x)
        if isinstance(x, torch.Tensor):
            return torch.where(self.log_mask.to(x.device), torch.log(torch.where(self.log_mask.to(x.device), x, 1.0)), x)
        x = np.asarray(x, dtype=np.float64)
        m = self.log_mask.cpu().numpy()
        return np.where(m, np.log(np.where(m, x, 1.0)), x)

    @torch.no_grad()
    def fit(self, data: np.ndarray | torch.Tensor) -> "LogStandardizer":
        """Mean and std of the features (log columns as logarithms) of ``data`` (N, dim)."""
        x = np.asarray(data.detach().cpu() if isinstance(data, torch.Tensor) else data, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.mean.numel():
            raise ValueError(f"expected (N, {self.mean.numel()}) data, got {x.shape}")
        return super().fit(self._log(x))

    def transform(self, x):
        """Physical -> standardized features."""
        return super().transform(self._log(x))

    def inverse(self, x):
        """Standardized features -> physical (``exp`` in the log columns)."""
        u = super().inverse(x)
        if isinstance(u, torch.Tensor):
            return torch.where(self.log_mask.to(u.device), torch.exp(u), u)
        return np.where(self.log_mask.cpu().numpy(), np.exp(u), u)


def _module_dtype_device(module: nn.Module) -> tuple[torch.dtype, torch.device]:
    p = next(module.parameters())
    return p.dtype, p.device


def _as_model_tensor(module: nn.Module, x) -> tuple[torch.Tensor, bool]:
    """Tensor on the module's device/dtype, and whether the input was numpy."""
    dtype, device = _module_dtype_device(module)
    if isinstance(x, torch.Tensor):
        return x.to(device=device, dtype=dtype), False
    return torch.as_tensor(np.array(x, dtype=np.float64), device=device).to(dtype), True


# ----------------------------------------------------------------------------- emulator
class Emulator(nn.Module):
    """``NN_e``: standardized parameters (N, n_in) -> standardized outputs (N, n_out).

    Two options beyond the paper's network (both off by default):

    * ``linear_skip``: the output is ``net(features) + skip(v_std)`` with ``skip`` a linear map
      (n_in -> n_out, with bias) initialized to zero, created after ``net`` so that both start
      from the same function as the plain MLP of the same seed. Outputs with an exactly linear
      part (SVR = R_a x 1000/60 x 80) need not be rebuilt from SiLUs, which miss it most at the
      prior's edge.
    * ``log_inputs`` (column indices): the MLP sees those parameters as logarithms,
      standardized (``feature_scaler``, fitted by :meth:`fit_features`); the other columns as
      ``v_std``. Below ``log_floor`` (half the smallest training value, physical units) the
      logarithm continues as its tangent line, so that a decoded parameter at or below zero
      still gives a finite output and gradient. The interface does not change: ``forward``
      takes ``v_std`` (``x_scaler``, physical units standardized) either way.
    """

    kind = "emulator"

    def __init__(self, hidden: int = 60, layers: int = 8, n_in: int = N_PARAMETERS,
                 n_out: int = N_OUTPUTS, activation: str = "silu", linear_skip: bool = False,
                 log_inputs: list[int] | tuple[int, ...] = ()):
        super().__init__()
        log_inputs = sorted({int(i) for i in log_inputs})
        if any(not 0 <= i < n_in for i in log_inputs):
            raise ValueError(f"log_inputs must be column indices in [0, {n_in}), got {log_inputs}")
        self.config = dict(hidden=int(hidden), layers=int(layers), n_in=int(n_in), n_out=int(n_out),
                           activation=str(activation), linear_skip=bool(linear_skip), log_inputs=log_inputs)
        self.net = MLP(n_in, n_out, hidden, layers, activation)
        self.skip = None
        if linear_skip:
            self.skip = nn.Linear(n_in, n_out)
            nn.init.zeros_(self.skip.weight)
            nn.init.zeros_(self.skip.bias)
        self.x_scaler = Standardizer(n_in)
        self.y_scaler = Standardizer(n_out)
        self.feature_scaler = None
        if log_inputs:
            mask = torch.zeros(n_in, dtype=torch.bool)
            mask[log_inputs] = True
            self.register_buffer("log_mask", mask)
            self.register_buffer("log_floor", torch.ones(n_in))
            self.feature_scaler = Standardizer(n_in)

    def _log_features(self, x: torch.Tensor) -> torch.Tensor:
        """Physical parameters -> the MLP's unstandardized features (log or linear per column)."""
        c = self.log_floor.to(x)
        safe_log = torch.where(x > c, torch.log(torch.maximum(x, c)), torch.log(c) + (x - c) / c)
        return torch.where(self.log_mask, safe_log, x)

    @torch.no_grad()
    def fit_features(self, v: np.ndarray) -> "Emulator":
        """Fit ``log_floor`` and ``feature_scaler`` to physical training parameters ``v`` (N, n_in);
        a no-op without ``log_inputs``. Raises ``ValueError`` naming a log column with a value <= 0."""
        if self.feature_scaler is None:
            return self
        v = np.asarray(v, dtype=np.float64)
        cols = self.config["log_inputs"]
        lo = v[:, cols].min(axis=0)
        if (lo <= 0).any():
            j = cols[int(np.argmax(lo <= 0))]
            raise ValueError(f"log_inputs column {j} has a training value <= 0 ({v[:, j].min()!r}); "
                             f"its logarithm is undefined")
        floor = np.ones(v.shape[1])
        floor[cols] = 0.5 * lo
        self.log_floor.copy_(torch.as_tensor(floor))
        self.feature_scaler.fit(self._log_features(torch.tensor(v)))  # float64
        return self

    def features(self, v_std: torch.Tensor) -> torch.Tensor:
        """The MLP's input for standardized parameters ``v_std``: ``v_std`` itself without
        ``log_inputs``."""
        if self.feature_scaler is None:
            return v_std
        return self.feature_scaler.transform(self._log_features(self.x_scaler.inverse(v_std)))

    def forward(self, v_std: torch.Tensor) -> torch.Tensor:
        y = self.net(self.features(v_std))
        return y if self.skip is None else y + self.skip(v_std)

    @torch.no_grad()
    def predict(self, v):
        """Physical parameters (N, 23) -> physical outputs (N, 16); numpy in, numpy out."""
        t, was_numpy = _as_model_tensor(self, v)
        was_training = self.training
        self.eval()
        y = self.y_scaler.inverse(self(self.x_scaler.transform(t)))
        self.train(was_training)
        return y.double().cpu().numpy() if was_numpy else y


# ----------------------------------------------------------------------------- flow
class AffineCoupling(nn.Module):
    """Real-NVP affine coupling on a split of the features into two halves.

    With halves ``a = x[:, :d]``, ``b = x[:, d:]``: if ``swap`` is False, ``a`` conditions and
    ``b`` is transformed, ``b' = b * exp(s(a)) + t(a)``; if True the roles are exchanged.
    ``s`` uses tanh, ``t`` ReLU activations, both MLPs with ``layers`` Linear layers and no
    output activation (as in the paper's code). log|det| = sum(s).
    """

    def __init__(self, dim: int, hidden: int, layers: int, swap: bool):
        super().__init__()
        self.d = dim // 2
        self.swap = bool(swap)
        n_cond, n_trans = (dim - self.d, self.d) if swap else (self.d, dim - self.d)
        self.s = MLP(n_cond, n_trans, hidden, layers, nn.Tanh)
        self.t = MLP(n_cond, n_trans, hidden, layers, nn.ReLU)

    def _split(self, x):
        a, b = x[:, : self.d], x[:, self.d:]
        return (b, a) if self.swap else (a, b)  # (conditioner, transformed)

    def _join(self, cond, trans):
        return torch.cat((trans, cond) if self.swap else (cond, trans), dim=1)

    def forward(self, x):
        cond, trans = self._split(x)
        s = self.s(cond)
        return self._join(cond, trans * torch.exp(s) + self.t(cond)), s.sum(dim=1)

    def inverse(self, z):
        cond, trans = self._split(z)
        s = self.s(cond)
        return self._join(cond, (trans - self.t(cond)) * torch.exp(-s)), -s.sum(dim=1)


class FlowBatchNorm(nn.Module):
    """Invertible batch normalization (Dinh et al. 2017), data -> latent direction.

    ``z = exp(log_gamma) * (x - mean) / sqrt(var + eps) + beta``, 2*dim parameters. In train
    mode ``forward`` uses the batch mean and (biased) variance and updates the running stats
    (torch convention: ``running = (1 - momentum) * running + momentum * batch``, unbiased
    batch variance); in eval mode it uses the running stats. ``inverse`` always uses the running
    stats (exact inverse of the eval-mode forward; sample in eval mode).
    """

    def __init__(self, dim: int, momentum: float = 0.1, eps: float = 1e-5):
        super().__init__()
        self.momentum, self.eps = float(momentum), float(eps)
        self.log_gamma = nn.Parameter(torch.zeros(dim))
        self.beta = nn.Parameter(torch.zeros(dim))
        self.register_buffer("running_mean", torch.zeros(dim))
        self.register_buffer("running_var", torch.ones(dim))

    def forward(self, x):
        if self.training:
            mean = x.mean(dim=0)
            var = x.var(dim=0, unbiased=False)
            with torch.no_grad():
                n = x.shape[0]
                unbiased = var * (n / max(n - 1, 1))
                self.running_mean.lerp_(mean.detach(), self.momentum)
                self.running_var.lerp_(unbiased.detach(), self.momentum)
        else:
            mean, var = self.running_mean, self.running_var
        z = torch.exp(self.log_gamma) * (x - mean) / torch.sqrt(var + self.eps) + self.beta
        logdet = (self.log_gamma - 0.5 * torch.log(var + self.eps)).sum().expand(x.shape[0])
        return z, logdet

    def inverse(self, z):
        mean, var = self.running_mean, self.running_var
        x = (z - self.beta) * torch.exp(-self.log_gamma) * torch.sqrt(var + self.eps) + mean
        logdet = (0.5 * torch.log(var + self.eps) - self.log_gamma).sum().expand(z.shape[0])
        return x, logdet


class RealNVP(nn.Module):
    """``NN_f``: Real-NVP density estimator of the standardized outputs, standard normal base.

    ``blocks`` affine couplings alternating which half (dim//2) is transformed, each followed by
    a :class:`FlowBatchNorm` when ``batchnorm`` (order in the data -> latent direction:
    coupling_1, [bn_1], coupling_2, [bn_2], ...). Structural study: hidden 24, 16 blocks, no
    BatchNorm = 51,712 parameters; EHR: hidden 18, 10 blocks, BatchNorm = 20,280.
    """

    kind = "flow"

    def __init__(self, dim: int = N_OUTPUTS, hidden: int = 24, blocks: int = 16,
                 layers_per_block: int = 4, batchnorm: bool = False):
        super().__init__()
        self.config = dict(dim=int(dim), hidden=int(hidden), blocks=int(blocks),
                           layers_per_block=int(layers_per_block), batchnorm=bool(batchnorm))
        self.dim = int(dim)
        layers: list[nn.Module] = []
        for k in range(blocks):
            layers.append(AffineCoupling(dim, hidden, layers_per_block, swap=bool(k % 2)))
            if batchnorm:
                layers.append(FlowBatchNorm(dim))
        self.layers = nn.ModuleList(layers)
        self.y_scaler = Standardizer(dim)

    def forward(self, y_std: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Data -> latent: ``(z (N, dim), log|det dz/dy| (N,))``."""
        logdet = y_std.new_zeros(y_std.shape[0])
        z = y_std
        for layer in self.layers:
            z, ld = layer(z)
            logdet = logdet + ld
        return z, logdet

    def inverse(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent -> data: ``(y_std (N, dim), log|det dy/dz| (N,))``."""
        logdet = z.new_zeros(z.shape[0])
        y = z
        for layer in reversed(self.layers):
            y, ld = layer.inverse(y)
            logdet = logdet + ld
        return y, logdet

    def log_prob(self, y_std: torch.Tensor) -> torch.Tensor:
        """log density of standardized outputs, (N,): ``log N(z; 0, I) + log|det dz/dy|``."""
        z, logdet = self(y_std)
        base = -0.5 * (z * z).sum(dim=1) - 0.5 * self.dim * math.log(2.0 * math.pi)
        return base + logdet

    @torch.no_grad()
    def log_prob_physical(self, y):
        """log density of physical outputs (N, 16), including the standardization Jacobian.

        Runs in eval mode. numpy in -> numpy out.
        """
        t, was_numpy = _as_model_tensor(self, y)
        was_training = self.training
        self.eval()
        lp = self.log_prob(self.y_scaler.transform(t)) - torch.log(self.y_scaler.std.to(t)).sum()
        self.train(was_training)
        return lp.double().cpu().numpy() if was_numpy else lp

    @torch.no_grad()
    def sample(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """``n`` standardized samples (n, dim), drawn in eval mode (running BatchNorm stats).

        ``z ~ N(0, I)`` is drawn on the generator's device (CPU if ``generator`` is None) and
        moved to the model's device.
        """
        dtype, device = _module_dtype_device(self)
        gdev = generator.device if generator is not None else torch.device("cpu")
        z = torch.randn(n, self.dim, generator=generator, device=gdev, dtype=dtype).to(device)
        was_training = self.training
        self.eval()
        y, _ = self.inverse(z)
        self.train(was_training)
        return y

    @torch.no_grad()
    def sample_physical(self, n: int, generator: torch.Generator | None = None) -> np.ndarray:
        """``n`` samples in physical units, numpy (n, dim) float64."""
        return self.y_scaler.inverse(self.sample(n, generator)).double().cpu().numpy()


# ----------------------------------------------------------------------------- encoder/decoder
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
        t, was_numpy = _as_model_tensor(self, y)
        wt, _ = _as_model_tensor(self, w)
        was_training = self.training
        self.eval()
        y_std = self.y_scaler.transform(t)
        v_std = self.decode(y_std, wt)
        for _ in range(int(corrector_steps)):
            v_std = self.decode(y_std, self.encode(v_std)[0])
        v = self.x_scaler.inverse(v_std)
        self.train(was_training)
        return v.double().cpu().numpy() if was_numpy else v


# ----------------------------------------------------------------------------- losses
def emulator_loss(y_pred_std: torch.Tensor, y_std: torch.Tensor) -> torch.Tensor:
    """Emulator MSE in standardized space: mean over batch and the 16 outputs (scalar)."""
    return torch.mean((y_pred_std - y_std) ** 2)


def flow_nll(flow: RealNVP, y_std: torch.Tensor) -> torch.Tensor:
    """Negative log-likelihood of standardized outputs, mean over the batch (scalar, nats)."""
    return -flow.log_prob(y_std).mean()


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


# ----------------------------------------------------------------------------- save / load
MODEL_CLASSES: dict[str, type[nn.Module]] = {
    Emulator.kind: Emulator, RealNVP.kind: RealNVP, EncoderDecoder.kind: EncoderDecoder,
}


def build_model(kind: str, config: dict) -> nn.Module:
    """Instantiate a model from its ``kind`` and architecture ``config``."""
    try:
        cls = MODEL_CLASSES[kind]
    except KeyError:
        raise ValueError(f"unknown model kind {kind!r}; one of {sorted(MODEL_CLASSES)}") from None
    return cls(**config)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (np.ndarray, torch.Tensor)):
        return obj.tolist()
    return str(obj)


def save_model(model: nn.Module, path: str | Path, info: dict | None = None) -> None:
    """Save ``model`` (weights, scalers, architecture) to one ``.pt`` file.

    The file is ``torch.save`` of ``{"format", "kind", "config", "state_dict", "info"}``;
    ``info`` is optional JSON-like metadata (hyperparameters, seed, final losses ...).
    Written atomically (temporary file + rename).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "kind": model.kind,
        "config": dict(model.config),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        # plain JSON types only, so that the file loads with ``weights_only=True``
        "info": json.loads(json.dumps(info or {}, default=_json_default)),
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def _read_payload(path: str | Path) -> dict:
    """The dictionary :func:`save_model` wrote, checked to be one (on the CPU)."""
    payload = torch.load(path, map_location="cpu", weights_only=True)
    fmt = payload.get("format") if isinstance(payload, dict) else None
    if fmt != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} model file (format={fmt!r})")
    return payload


def read_info(path: str | Path) -> dict:
    """The ``info`` a model file holds (training record, origin, noise level), without building
    the model."""
    return _read_payload(path).get("info", {})


def load_model(path: str | Path, map_location: str | torch.device = "cpu", with_info: bool = False):
    """Rebuild a model saved by :func:`save_model`, in eval mode on ``map_location``.

    With ``with_info=True`` returns ``(model, info)``.
    """
    payload = _read_payload(path)
    model = build_model(payload["kind"], payload["config"])
    dtype = next(t.dtype for t in payload["state_dict"].values() if t.is_floating_point())
    model.to(dtype=dtype)
    model.load_state_dict(payload["state_dict"])
    model.to(map_location).eval()
    return (model, payload.get("info", {})) if with_info else model
