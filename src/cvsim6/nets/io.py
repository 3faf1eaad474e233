"""Saving and loading the inVAErt networks: one self-contained ``.pt`` file per network."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cvsim6.model_files import FORMAT, read_info, read_payload
from cvsim6.nets.emulator import Emulator
from cvsim6.nets.encoder_decoder import EncoderDecoder
from cvsim6.nets.flow import RealNVP

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


def load_model(path: str | Path, map_location: str | torch.device = "cpu", with_info: bool = False):
    """Rebuild a model saved by :func:`save_model`, in eval mode on ``map_location``.

    With ``with_info=True`` returns ``(model, info)``.
    """
    payload = read_payload(path)
    model = build_model(payload["kind"], payload["config"])
    dtype = next(t.dtype for t in payload["state_dict"].values() if t.is_floating_point())
    model.to(dtype=dtype)
    model.load_state_dict(payload["state_dict"])
    model.to(map_location).eval()
    return (model, payload.get("info", {})) if with_info else model
