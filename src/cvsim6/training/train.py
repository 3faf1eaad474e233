"""The three training entry points, one per inVAErt stage (file-based, for Snakemake).

* :func:`train_emulator` -- ``NN_e``, MSE in standardized space, never with noise.
* :func:`train_flow` -- ``NN_f``, negative log-likelihood of the (noisy) standardized outputs.
* :func:`train_encoder_decoder` -- ``NN_v`` + ``NN_d`` through the frozen trained emulator.

All paths are strings; datasets are Parquet splits with the 23 parameter and 16 output columns
in clinical units. ``hyper`` is checked and completed by
:func:`cvsim6.training.hyperparameters.check_hyper` (the keys: the workflow schema's
``$defs/<stage>_hyper``). Standardizers are fitted on the training split (clean outputs) and
saved in the model; the model is built after ``torch.manual_seed`` of its initialization seed,
the test split's fixed noise and ``eps`` come from a generator seeded ``derived_seed(seed, 2)``.
The epoch loop, losses CSV and checkpoints: :mod:`cvsim6.training.loop`; best of ``restarts``
initializations: :mod:`cvsim6.training.restarts`.
"""
from __future__ import annotations

import numpy as np
import torch

from cvsim6 import nets as nw
from cvsim6.data.datasets import load_split
from cvsim6.registry import noise_std
from cvsim6.seeding import derived_seed
from cvsim6.training.fingerprint import array_digest, file_digest, run_fingerprint
from cvsim6.training.hyperparameters import check_hyper
from cvsim6.training.loss_weights import relative_sample_weights, variance_floor_matrix
from cvsim6.training.optimization import resolve_device
from cvsim6.training.restarts import train_with_restarts
from cvsim6.training.stages import EmulatorStage, EncoderDecoderStage, FlowStage


def _setup(stage: str, hyper: dict, device: str, threads: int) -> tuple[dict, torch.device, torch.dtype]:
    """The checked ``hyper`` of ``stage``, the device and the dtype; sets torch's thread count."""
    h = check_hyper(stage, hyper)
    torch.set_num_threads(int(threads))
    return h, resolve_device(device), getattr(torch, h["dtype"])


def inflate_output_scale(scaler: nw.Standardizer, noise_level: float) -> None:
    """Widen a fitted output standardizer to the std of the *noisy* outputs,
    ``sqrt(std^2 + (delta * s)^2)`` per output (s: registry noise std, clinical units), as the
    paper's public code standardizes in its noisy studies. No change when ``noise_level`` is 0."""
    if noise_level == 0:
        return
    s = torch.as_tensor(noise_std(), dtype=torch.float64) * float(noise_level)
    with torch.no_grad():
        scaler.std.copy_(torch.sqrt(scaler.std.double() ** 2 + s ** 2).to(scaler.std))


def positive_columns(v: np.ndarray) -> list[int]:
    """Indices of the columns of ``v`` (N, n) whose values are all > 0: the parameters the
    ``log_inputs`` / ``log_parameters`` options take logarithms of (in CVSim-6 all but P_th)."""
    return [j for j in range(v.shape[1]) if v[:, j].min() > 0]


def train_emulator(train: str, test: str, model: str, losses: str, hyper: dict, seed: int,
                   device: str = "auto", threads: int = 1, checkpoint: str | None = None,
                   max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                   progress: bool = True, max_cpu_seconds: float | None = None,
                   candidate: int | None = None, candidates: list[str] | None = None) -> dict:
    """Train ``NN_e`` (parameters -> outputs) on clean data; write ``model`` (.pt) and ``losses``
    (CSV, one row per epoch; :func:`cvsim6.reporting.loss_figures.plot_training_losses` draws it).
    ``max_epochs_this_run`` stops early after that many epochs of this call (checkpoint only,
    no model written). With ``restarts``: ``candidate`` trains that initialization only, to the
    choice, at ``checkpoint`` (``losses`` = checkpoint + ".csv"; no model written), and
    ``candidates`` names the candidates' checkpoints (see
    :func:`~cvsim6.training.restarts.train_with_restarts`). Returns a summary dict
    (``completed``, ``epochs_done``, ``train_loss``, ``test_loss``; a candidate's ``score``)."""
    h, dev, dtype = _setup("emulator", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)

    log_cols = positive_columns(v_tr) if h["log_inputs"] else []

    def make_stage(init_seed: int) -> EmulatorStage:
        torch.manual_seed(init_seed)
        net = nw.Emulator(h["hidden"], h["layers"], activation=h["activation"], linear_skip=h["linear_skip"],
                          log_inputs=log_cols)
        net.x_scaler.fit(v_tr)
        net.fit_features(v_tr)
        net.y_scaler.fit(y_tr)
        net.to(dev, dtype)
        y_tr_std = net.y_scaler.transform(y_tr)
        weighting = None if h["variance_floor"] is None else variance_floor_matrix(y_tr_std, h["variance_floor"])
        a = h["relative_weight"]
        rows = None if a == 0 else (relative_sample_weights(y_tr, y_tr, a), relative_sample_weights(y_tr, y_te, a))
        return EmulatorStage(net, net.x_scaler.transform(v_tr), y_tr_std,
                             net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), dev, dtype, weighting, rows)

    fp = run_fingerprint(stage="emulator", hyper=h, seed=seed, data=array_digest(v_tr, y_tr, v_te, y_te),
                         fmt=nw.FORMAT)
    info = {"stage": "emulator", "hyper": h, "seed": seed, "noise_level": 0.0, "n_train": len(v_tr), "n_test": len(v_te)}
    return train_with_restarts(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)


def train_flow(train: str, test: str, model: str, losses: str, hyper: dict, seed: int,
               noise_level: float = 0.0, device: str = "auto", threads: int = 1, checkpoint: str | None = None,
               max_epochs_this_run: int | None = None, checkpoint_every: int = 50, progress: bool = True,
               max_cpu_seconds: float | None = None, candidate: int | None = None,
               candidates: list[str] | None = None) -> dict:
    """Train the Real-NVP ``NN_f`` on the outputs with training noise of level ``noise_level``
    (delta, multiplier of the registry noise std). Outputs and return value as
    :func:`train_emulator`."""
    h, dev, dtype = _setup("flow", hyper, device, threads)
    _, y_tr = load_split(train)
    _, y_te = load_split(test)

    def make_stage(init_seed: int) -> FlowStage:
        torch.manual_seed(init_seed)
        net = nw.RealNVP(hidden=h["hidden"], blocks=h["blocks"], layers_per_block=h["layers_per_block"],
                         batchnorm=bool(h["batchnorm"]))
        net.y_scaler.fit(y_tr)
        if h["noisy_scaling"]:
            inflate_output_scale(net.y_scaler, noise_level)
        net.to(dev, dtype)
        test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
        return FlowStage(net, net.y_scaler.transform(y_tr), net.y_scaler.transform(y_te), noise_level, test_gen,
                         dev, dtype)

    fp = run_fingerprint(stage="flow", hyper=h, seed=seed, noise=float(noise_level), data=array_digest(y_tr, y_te),
                         noise_std=noise_std().tolist(), fmt=nw.FORMAT)
    info = {"stage": "flow", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(y_tr), "n_test": len(y_te), "label": f"delta={noise_level:g}"}
    return train_with_restarts(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)


def encoder_decoder_net(h: dict, log_cols: list[int]) -> nw.EncoderDecoder:
    """An untrained ``NN_v`` + ``NN_d`` of the checked hyperparameters ``h``, decoding the logarithms
    of parameters ``log_cols``."""
    return nw.EncoderDecoder(latent_dim=h["latent_dim"], encoder_hidden=h["encoder_hidden"],
                             encoder_layers=h["encoder_layers"], decoder_hidden=h["decoder_hidden"],
                             decoder_layers=h["decoder_layers"], activation=h["activation"],
                             logvar_max=h["logvar_max"], log_params=log_cols)


def encoder_decoder_fingerprint(h: dict, seed: int, noise_level: float, splits: tuple, emulator: str) -> str:
    """Identity of an encoder/decoder run (:mod:`cvsim6.training.fingerprint`): checked ``h``, the
    master ``seed``, ``noise_level``, the ``splits`` (v_train, y_train, v_test, y_test) and the
    ``emulator`` file's contents. Its checkpoint holds it; a benchmark that continues a restart
    candidate under another schedule writes it into the candidate's checkpoint."""
    return run_fingerprint(stage="encoder_decoder", hyper=h, seed=seed, noise=float(noise_level),
                           data=array_digest(*splits), emulator=file_digest(emulator),
                           noise_std=noise_std().tolist(), fmt=nw.FORMAT)


def train_encoder_decoder(train: str, test: str, emulator: str, model: str, losses: str,
                          hyper: dict, seed: int, noise_level: float = 0.0, device: str = "auto",
                          threads: int = 1, checkpoint: str | None = None,
                          max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                          progress: bool = True, max_cpu_seconds: float | None = None,
                          candidate: int | None = None, candidates: list[str] | None = None) -> dict:
    """Train ``NN_v`` + ``NN_d`` with the re-evaluation term through the frozen emulator file
    ``emulator``; training noise of level ``noise_level`` on y' everywhere. Outputs and return
    value as :func:`train_emulator`."""
    h, dev, dtype = _setup("encoder_decoder", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)
    emu = nw.load_model(emulator, map_location=dev)
    if not isinstance(emu, nw.Emulator):
        raise ValueError(f"{emulator}: expected an emulator model, got {type(emu).__name__}")
    emu.to(dtype=dtype).eval().requires_grad_(False)
    log_cols = positive_columns(v_tr) if h["log_parameters"] else []

    def make_stage(init_seed: int) -> EncoderDecoderStage:
        torch.manual_seed(init_seed)
        net = encoder_decoder_net(h, log_cols)
        net.x_scaler.fit(v_tr)
        net.y_scaler.fit(y_tr)
        if h["noisy_scaling"]:
            inflate_output_scale(net.y_scaler, noise_level)
        net.to(dev, dtype)
        test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
        return EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                                   net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), noise_level, h,
                                   test_gen, dev, dtype)

    fp = encoder_decoder_fingerprint(h, seed, noise_level, (v_tr, y_tr, v_te, y_te), emulator)
    info = {"stage": "encoder_decoder", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(v_tr), "n_test": len(v_te), "label": f"delta={noise_level:g}"}
    return train_with_restarts(make_stage, h, seed, fp, model, losses, checkpoint, info, max_epochs_this_run, checkpoint_every,
                  progress, max_cpu_seconds, candidate, candidates)
