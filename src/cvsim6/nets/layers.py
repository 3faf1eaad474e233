"""Building blocks of the inVAErt networks: MLPs, standardizers, parameter counts.

Every network works in *standardized* space (training-set mean/std, :class:`Standardizer`);
each model carries its own ``x_scaler``/``y_scaler`` buffers, so a saved model file is
self-contained.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

_ACTIVATIONS: dict[str, type[nn.Module]] = {
    "silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU, "gelu": nn.GELU, "elu": nn.ELU,
}


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters of ``module`` (buffers such as scalers excluded)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def make_activation(activation: str | type[nn.Module] | Callable[[], nn.Module]) -> Callable[[], nn.Module]:
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
        act = make_activation(activation)
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


def module_dtype_device(module: nn.Module) -> tuple[torch.dtype, torch.device]:
    p = next(module.parameters())
    return p.dtype, p.device


def as_model_tensor(module: nn.Module, x) -> tuple[torch.Tensor, bool]:
    """Tensor on the module's device/dtype, and whether the input was numpy."""
    dtype, device = module_dtype_device(module)
    if isinstance(x, torch.Tensor):
        return x.to(device=device, dtype=dtype), False
    return torch.as_tensor(np.array(x, dtype=np.float64), device=device).to(dtype), True
