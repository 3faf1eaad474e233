"""The density estimator ``NN_f``: a Real-NVP affine coupling flow on the 16 outputs.

Direction convention: ``forward`` maps **data -> latent** (y -> z) and returns
``log|det dz/dy|``; ``inverse`` maps latent -> data and returns ``log|det dy/dz|``.
``log_prob(y) = log N(z; 0, I) + log|det dz/dy|``, identical to the paper's
``log pi_0(z^(0)) - sum_l log|det dz^(l)/dz^(l-1)|`` whose layers run latent -> data.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from cvsim6.nets.layers import MLP, Standardizer, as_model_tensor, module_dtype_device
from cvsim6.registry import N_OUTPUTS


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
        t, was_numpy = as_model_tensor(self, y)
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
        dtype, device = module_dtype_device(self)
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


def flow_nll(flow: RealNVP, y_std: torch.Tensor) -> torch.Tensor:
    """Negative log-likelihood of standardized outputs, mean over the batch (scalar, nats)."""
    return -flow.log_prob(y_std).mean()
