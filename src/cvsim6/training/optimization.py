"""Device, optimizer and learning-rate schedule of a training run."""
from __future__ import annotations

import math

import torch


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
