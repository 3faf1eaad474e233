"""Identity of a training run, kept in its checkpoints: a checkpoint is resumed only by the run
(stage, hyperparameters, seed, noise level, data and emulator contents, training code) that
wrote it; any other run ignores and overwrites it."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

#: The package sources training code may import, relative to the package folder: a folder
#: stands for every source file under it. All of them enter :func:`training_code_digest`.
DIGEST_SOURCES = ("__init__.py", "registry.py", "seeding.py", "model_files.py", "workflow/__init__.py",
                  "workflow/config.py", "model", "data", "nets", "training")


def array_digest(*arrays: np.ndarray) -> str:
    """sha256 over the shapes and bytes of ``arrays``."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def file_digest(path: str | Path) -> str:
    """sha256 of the file at ``path``."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def training_code_digest() -> str:
    """sha256 over the training subpackage's sources and those of the layers below it
    (:data:`DIGEST_SOURCES`): a superset of the files the workflow's training rules declare
    as their ``code`` input, so a code change that reruns a training rule also retires its
    checkpoints."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(f for source in DIGEST_SOURCES for f in
                   ([root / source] if source.endswith(".py") else (root / source).rglob("*.py")))
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def run_fingerprint(**items) -> str:
    """Identity of a training run: the given items plus the training code's digest, so a
    checkpoint (finished ones included) is reused only by the code that wrote it and a rule
    rerun after a code change retrains instead of re-saving old weights."""
    items = {**items, "code": training_code_digest()}
    return hashlib.sha256(json.dumps(items, sort_keys=True, default=str).encode()).hexdigest()
