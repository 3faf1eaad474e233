"""The emulator ``NN_e``: parameters (N, 23) -> clinical outputs (N, 16) (paper section 2.2).

MLP 23 -> 16, SiLU (hidden 60 x 8 layers = 24,376 parameters; hidden 80 = 42,096); optionally
plus a linear map of the inputs (``linear_skip``, 384 parameters more; not in the paper).
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from cvsim6.nets.layers import MLP, LogStandardizer, Standardizer, as_model_tensor
from cvsim6.registry import N_OUTPUTS, N_PARAMETERS


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
        t, was_numpy = as_model_tensor(self, v)
        was_training = self.training
        self.eval()
        y = self.y_scaler.inverse(self(self.x_scaler.transform(t)))
        self.train(was_training)
        return y.double().cpu().numpy() if was_numpy else y


def emulator_loss(y_pred_std: torch.Tensor, y_std: torch.Tensor) -> torch.Tensor:
    """Emulator MSE in standardized space: mean over batch and the 16 outputs (scalar)."""
    return torch.mean((y_pred_std - y_std) ** 2)
