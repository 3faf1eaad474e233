"""Shared pieces of the training tests: a synthetic dataset, tiny hyperparameters, a trained emulator."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import torch

from cvsim6.training import train as tr
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES, default_parameters, noise_std


EMU = dict(hidden=32, layers=3, epochs=25, batch_size=32, lr=3e-3, lr_step=10, lr_gamma=0.7)
FLOW = dict(hidden=16, blocks=4, layers_per_block=4, batchnorm=True, epochs=40, batch_size=64, lr=5e-3,
            lr_step=20, lr_gamma=0.7, weight_decay=1e-5)
ENCDEC = dict(latent_dim=7, encoder_hidden=16, encoder_layers=3, decoder_hidden=32, decoder_layers=3,
              beta_d=1.0, beta_v=0.05, beta_r=0.5, epochs=25, batch_size=32, lr=3e-3, lr_step=10, lr_gamma=0.7)


def synthetic(n: int, seed: int) -> pd.DataFrame:
    """Smooth map 23 -> 16 with outputs on the scale of the registry noise (x 10)."""
    rng = np.random.default_rng(seed)
    v = default_parameters() * rng.uniform(0.7, 1.3, size=(n, 23))
    u = (v / default_parameters() - 1.0) / 0.3  # in [-1, 1]
    a = np.random.default_rng(123).normal(size=(23, 16)) / np.sqrt(23)
    y = np.tanh(u @ a) + 0.3 * np.sin(2 * u[:, :16])
    y = 100.0 + 10.0 * noise_std() * y
    y[:, 0] = v[:, 0]  # output Hr is the input Hr: one shared column, as in the real datasets
    df = pd.DataFrame(v, columns=list(PARAMETER_NAMES))
    for j, name in enumerate(OUTPUT_NAMES):
        df[name] = y[:, j]
    assert df.shape[1] == 38
    return df


def write_synthetic_split(d: Path) -> tuple[Path, Path]:
    """A synthetic training split in folder ``d``: 400 training and 100 test rows."""
    synthetic(400, 1).to_parquet(d / "train.parquet")
    synthetic(100, 2).to_parquet(d / "test.parquet")
    return d / "train.parquet", d / "test.parquet"


def paths(d, name):
    return dict(model=str(d / f"{name}.pt"), losses=str(d / f"{name}.csv"))


def train_tiny_emulator(data, d: Path):
    """The tiny emulator (``EMU``) of the training tests, trained on ``data`` into folder ``d``."""
    return d, tr.train_emulator(str(data[0]), str(data[1]), hyper=EMU, seed=0, device="cpu", progress=False,
                                **paths(d, "emulator"))


def state_dict(path):
    return torch.load(path, weights_only=True)["state_dict"]


def assert_same_weights(a, b):
    sa, sb = state_dict(a), state_dict(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


RESTARTS = {"epochs": 6, "restarts": 3, "restart_epochs": 2}


def encdec_run(data, emulator, d, hyper, checkpoint_every=2, **kw):
    d.mkdir(exist_ok=True)
    return tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                    hyper=ENCDEC | hyper, seed=3, noise_level=0.25, device="cpu", progress=False,
                                    checkpoint_every=checkpoint_every, **paths(d, "m"), **kw)


def drop_timing(df):
    return df.drop(columns=["seconds", "cpu_seconds"]).reset_index(drop=True)


SCREEN = RESTARTS | {"restart_target": 0.1, "max_restarts": 6}

