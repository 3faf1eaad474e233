"""The format of a network's ``.pt`` file: its version tag and how to read it back checked.

Kept apart from :mod:`cvsim6.nets` (which writes these files and rebuilds the networks) so
that a reader of the training record, such as the loss figures, does not depend on the
networks' code."""
from __future__ import annotations

from pathlib import Path

import torch

#: Version tag stored in every saved model file.
FORMAT = "cvsim6-invaert/1"


def read_payload(path: str | Path) -> dict:
    """The dictionary :func:`cvsim6.nets.io.save_model` wrote, checked to be one (on the CPU)."""
    payload = torch.load(path, map_location="cpu", weights_only=True)
    fmt = payload.get("format") if isinstance(payload, dict) else None
    if fmt != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} model file (format={fmt!r})")
    return payload


def read_info(path: str | Path) -> dict:
    """The ``info`` a model file holds (training record, origin, noise level), without building
    the model."""
    return read_payload(path).get("info", {})
