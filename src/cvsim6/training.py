"""Resumable, seeded training of the three inVAErt stages (file-based, for Snakemake).

Entry points (all paths are strings; datasets are Parquet splits with the 23 parameter and
16 output columns in clinical units):

* :func:`train_emulator` -- ``NN_e``, MSE in standardized space, never with noise.
* :func:`train_flow` -- ``NN_f``, negative log-likelihood of the (noisy) standardized outputs.
* :func:`train_encoder_decoder` -- ``NN_v`` + ``NN_d`` through the frozen trained emulator.

``hyper`` keys
--------------
Common (required): ``epochs`` (int), ``batch_size`` (int), ``lr`` (initial Adam learning
rate), ``lr_step`` (epochs per StepLR decay), ``lr_gamma`` (decay factor).
Common (optional): ``weight_decay`` (Adam L2 penalty, default 0), ``grad_clip`` (max global
gradient norm, 0 = off, default 0; the paper's code clips the structural flow at 10).

* emulator: ``hidden``, ``layers`` (Linear layers in total); optional ``activation`` ("silu").
* flow: ``hidden``, ``blocks``, ``layers_per_block`` (Linear layers per s/t net, paper 4),
  ``batchnorm`` (bool).
* encoder_decoder: ``latent_dim``, ``encoder_hidden``, ``encoder_layers``, ``decoder_hidden``,
  ``decoder_layers``, ``beta_d``, ``beta_v``, ``beta_r``; optional ``reduction`` ("sum":
  per-sample squared norms averaged over the batch, the paper's equation; "mse": mean over
  batch and components, the paper's public code), ``activation`` ("silu").

Unknown keys raise ``ValueError``.

Training procedure
------------------
* Standardizers are fitted on the training split (clean outputs) and saved in the model.
* Noise (flow, encoder/decoder, re-evaluation term; delta = ``noise_level``): once per epoch a
  fresh draw ``eta ~ N(0, diag((delta*s)^2))`` in physical units for the whole training set,
  added to y and then standardized (``y_std + eta / std_y``). Never for the emulator.
* Randomness: ``torch.manual_seed(seed)`` before building the model (initial weights); one CPU
  ``torch.Generator`` (derived from ``seed``) draws, per epoch and in this order, the noise, the
  reparameterization ``eps`` (encoder/decoder) and the minibatch permutation. Test losses use
  one fixed noise/eps draw from a second derived generator. Results are bit-reproducible on
  CPU for a fixed thread count.
* Minibatches: whole tensors on the device, indexed by a permutation; a trailing batch of a
  single sample is dropped (BatchNorm needs two).
* Adam (``fused=True`` when supported) + StepLR stepped once per epoch.
* Losses CSV columns: ``epoch`` (1-based), ``train_loss`` (sample-weighted mean over the
  epoch's minibatches, in train mode), ``test_loss`` (eval mode, full test split), ``lr``
  (learning rate used in that epoch), ``seconds`` (wall time of that epoch), then per-term
  columns for the encoder/decoder (unweighted ``decoder``, ``kl``, ``reeval`` terms).
* Checkpoints (model, optimizer, scheduler, RNG states, history, epoch) every
  ``checkpoint_every`` epochs and at the end, written atomically to ``checkpoint`` (default
  ``model + ".ckpt"``). A rerun with the same arguments resumes from it and yields the same
  final weights as an uninterrupted run. A checkpoint whose fingerprint (stage, hyper, seed,
  noise level, data and emulator contents) differs is ignored and overwritten.
"""
from __future__ import annotations

import csv
import hashlib
import json
import logging
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from torch import nn

from . import networks as nw
from .datasets import load_split
from .registry import noise_std

log = logging.getLogger(__name__)

_COMMON_REQUIRED = ("epochs", "batch_size", "lr", "lr_step", "lr_gamma")
_COMMON_OPTIONAL = {"weight_decay": 0.0, "grad_clip": 0.0}
HYPER_KEYS: dict[str, tuple[tuple[str, ...], dict]] = {
    "emulator": (_COMMON_REQUIRED + ("hidden", "layers"), {**_COMMON_OPTIONAL, "activation": "silu"}),
    "flow": (_COMMON_REQUIRED + ("hidden", "blocks", "layers_per_block", "batchnorm"), dict(_COMMON_OPTIONAL)),
    "encoder_decoder": (
        _COMMON_REQUIRED + ("latent_dim", "encoder_hidden", "encoder_layers", "decoder_hidden",
                            "decoder_layers", "beta_d", "beta_v", "beta_r"),
        {**_COMMON_OPTIONAL, "reduction": "sum", "activation": "silu"},
    ),
}
_EVAL_CHUNK = 65536


# ----------------------------------------------------------------------------- helpers
def check_hyper(stage: str, hyper: dict) -> dict:
    """Validated copy of ``hyper`` for ``stage`` with optional keys filled in."""
    required, optional = HYPER_KEYS[stage]
    missing = [k for k in required if k not in hyper]
    unknown = sorted(set(hyper) - set(required) - set(optional))
    if missing or unknown:
        raise ValueError(f"{stage} hyperparameters: missing {missing}, unknown {unknown}")
    h = {**optional, **hyper}
    for k in ("epochs", "batch_size", "lr_step"):
        if int(h[k]) != h[k] or h[k] < 1:
            raise ValueError(f"{stage} hyperparameter {k} must be a positive integer, got {h[k]!r}")
    if stage == "encoder_decoder" and h["reduction"] not in ("sum", "mse"):
        raise ValueError(f"reduction must be 'sum' or 'mse', got {h['reduction']!r}")
    return h


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


def derived_seed(seed: int, stream: int) -> int:
    """Independent 63-bit seed for random stream ``stream`` of master ``seed``."""
    return int(np.random.SeedSequence([int(seed), int(stream)]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _to_device(a: np.ndarray | torch.Tensor, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(a).to(dtype=torch.float32).to(device)


def _std_noise(n: int, noise_level: float, generator: torch.Generator, y_std_scale: torch.Tensor) -> torch.Tensor | None:
    """Per-sample noise in standardized units, (n, 16) float64 CPU, or None when delta == 0."""
    if noise_level == 0:
        return None
    return nw.draw_noise(n, noise_level, generator) / y_std_scale


# ----------------------------------------------------------------------------- stages
class _Stage:
    """What the generic loop needs from one training stage."""

    name = ""
    parts: tuple[str, ...] = ()
    model: nn.Module

    def __init__(self, n_train: int, device: torch.device):
        self.n_train, self.device = n_train, device

    def begin_epoch(self, generator: torch.Generator) -> None:
        """Draw this epoch's random inputs (noise, eps) from ``generator``."""

    def batch_loss(self, idx: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        raise NotImplementedError

    def evaluate(self) -> tuple[float, dict[str, float]]:
        raise NotImplementedError


def _chunked_mean(n: int, fn: Callable[[slice], tuple[torch.Tensor, dict]]) -> tuple[float, dict[str, float]]:
    total, parts = 0.0, {}
    for start in range(0, n, _EVAL_CHUNK):
        sl = slice(start, min(n, start + _EVAL_CHUNK))
        w = (sl.stop - sl.start) / n
        loss, p = fn(sl)
        total += float(loss) * w
        for k, v in p.items():
            parts[k] = parts.get(k, 0.0) + float(v) * w
    return total, parts


class EmulatorStage(_Stage):
    """MSE of ``NN_e`` on clean standardized data (no noise, no randomness besides shuffling)."""

    name = "emulator"

    def __init__(self, model: nw.Emulator, v_tr, y_tr, v_te, y_te, device):
        super().__init__(len(v_tr), device)
        self.model = model
        self.v_tr, self.y_tr = _to_device(v_tr, device), _to_device(y_tr, device)
        self.v_te, self.y_te = _to_device(v_te, device), _to_device(y_te, device)
        self.y_epoch = self.y_tr  # targets of the current epoch: always the clean data

    def batch_loss(self, idx):
        return nw.emulator_loss(self.model(self.v_tr[idx]), self.y_epoch[idx]), {}

    @torch.no_grad()
    def evaluate(self):
        return _chunked_mean(len(self.v_te), lambda s: (nw.emulator_loss(self.model(self.v_te[s]), self.y_te[s]), {}))


class FlowStage(_Stage):
    """NLL of ``NN_f`` on noisy standardized outputs (fresh noise every epoch)."""

    name = "flow"

    def __init__(self, model: nw.RealNVP, y_tr, y_te, noise_level: float, test_generator, device):
        super().__init__(len(y_tr), device)
        self.model, self.noise_level = model, float(noise_level)
        self.scale = model.y_scaler.std.detach().double().cpu()
        self.y_tr = _to_device(y_tr, device)
        self.y_epoch = self.y_tr
        noise = _std_noise(len(y_te), self.noise_level, test_generator, self.scale)
        self.y_te = _to_device(y_te if noise is None else torch.as_tensor(y_te) + noise, device)

    def begin_epoch(self, generator):
        noise = _std_noise(self.n_train, self.noise_level, generator, self.scale)
        self.y_epoch = self.y_tr if noise is None else self.y_tr + _to_device(noise, self.device)

    def batch_loss(self, idx):
        return nw.flow_nll(self.model, self.y_epoch[idx]), {}

    @torch.no_grad()
    def evaluate(self):
        return _chunked_mean(len(self.y_te), lambda s: (nw.flow_nll(self.model, self.y_te[s]), {}))


class EncoderDecoderStage(_Stage):
    """Encoder/decoder loss with noisy y' (decoder input and re-evaluation target)."""

    name = "encoder_decoder"
    parts = ("decoder", "kl", "reeval")

    def __init__(self, model: nw.EncoderDecoder, emulator: nw.Emulator, v_tr, y_tr, v_te, y_te,
                 noise_level: float, hyper: dict, test_generator, device):
        super().__init__(len(v_tr), device)
        self.model, self.noise_level = model, float(noise_level)
        self.emulator = emulator
        self.reevaluate = nw.make_reevaluator(emulator, model)
        self.betas = (float(hyper["beta_d"]), float(hyper["beta_v"]), float(hyper["beta_r"]))
        self.reduction = hyper["reduction"]
        self.latent = model.latent_dim
        self.scale = model.y_scaler.std.detach().double().cpu()
        self.v_tr, self.y_tr = _to_device(v_tr, device), _to_device(y_tr, device)
        self.v_te = _to_device(v_te, device)
        noise = _std_noise(len(y_te), self.noise_level, test_generator, self.scale)
        self.y_te = _to_device(y_te if noise is None else torch.as_tensor(y_te) + noise, device)
        self.eps_te = _to_device(torch.randn(len(v_te), self.latent, generator=test_generator), device)
        self.y_epoch, self.eps_epoch = self.y_tr, None

    def begin_epoch(self, generator):
        noise = _std_noise(self.n_train, self.noise_level, generator, self.scale)
        self.y_epoch = self.y_tr if noise is None else self.y_tr + _to_device(noise, self.device)
        self.eps_epoch = _to_device(torch.randn(self.n_train, self.latent, generator=generator), self.device)

    def _loss(self, v, y, eps):
        return nw.encoder_decoder_loss(self.model, v, y, eps, self.reevaluate, *self.betas, reduction=self.reduction)

    def batch_loss(self, idx):
        return self._loss(self.v_tr[idx], self.y_epoch[idx], self.eps_epoch[idx])

    @torch.no_grad()
    def evaluate(self):
        return _chunked_mean(len(self.v_te), lambda s: self._loss(self.v_te[s], self.y_te[s], self.eps_te[s]))


# ----------------------------------------------------------------------------- outputs
def _columns(stage: _Stage) -> list[str]:
    cols = ["epoch", "train_loss", "test_loss", "lr", "seconds"]
    cols += [f"train_{p}" for p in stage.parts] + [f"test_{p}" for p in stage.parts]
    return cols


def _write_rows(path: Path, columns: list[str], rows: list[dict], mode: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, mode, newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        if mode == "w":
            w.writeheader()
        for r in rows:
            w.writerow({k: (repr(float(r[k])) if k != "epoch" else int(r[k])) for k in columns})


def _log_axis(ax, values: np.ndarray) -> None:
    """Log-scale y; plain numbers on the ticks when the data span less than a decade."""
    from matplotlib.ticker import FormatStrFormatter

    ax.set_yscale("log")
    if values.max() / values.min() < 10.0:
        ax.yaxis.set_major_formatter(FormatStrFormatter("%.3g"))
        ax.yaxis.set_minor_formatter(FormatStrFormatter("%.3g"))


def plot_losses(losses_csv: str | Path, figure: str | Path, title: str = "", ylabel: str = "loss") -> None:
    """PNG loss curve from a losses CSV: train and test, log-scale y (linear when a loss is
    not positive, e.g. a flow NLL); encoder/decoder CSVs get a second panel per loss term."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    df = pd.read_csv(losses_csv)
    parts = [c[len("train_"):] for c in df.columns if c.startswith("train_") and c != "train_loss"]
    fig, axes = plt.subplots(1, 2 if parts else 1, figsize=(12 if parts else 7, 4.5), squeeze=False)
    ax = axes[0, 0]
    ax.plot(df["epoch"], df["train_loss"], label="train", lw=1.2)
    ax.plot(df["epoch"], df["test_loss"], label="test", lw=1.2)
    vals = np.concatenate([df["train_loss"].to_numpy(), df["test_loss"].to_numpy()])
    vals = vals[np.isfinite(vals)]
    if vals.size and (vals > 0).all():
        _log_axis(ax, vals)
    elif vals.size:
        lo, hi = np.quantile(vals, [0.0, 0.98])
        pad = 0.05 * (hi - lo if hi > lo else 1.0)
        ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("epoch")
    ax.set_ylabel(ylabel)
    ax.set_title(title or "loss")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if parts:
        ax2 = axes[0, 1]
        for i, p in enumerate(parts):
            color = f"C{i}"
            ax2.plot(df["epoch"], df[f"train_{p}"], color=color, lw=1.2, label=f"{p} (train)")
            ax2.plot(df["epoch"], df[f"test_{p}"], color=color, lw=1.2, ls="--", label=f"{p} (test)")
        pv = df[[f"train_{p}" for p in parts] + [f"test_{p}" for p in parts]].to_numpy().ravel()
        pv = pv[np.isfinite(pv)]
        if pv.size and (pv > 0).all():
            _log_axis(ax2, pv)
        ax2.set_xlabel("epoch")
        ax2.set_ylabel("unweighted term")
        ax2.set_title("loss terms")
        ax2.grid(True, which="both", alpha=0.3)
        ax2.legend(fontsize="small")
    fig.tight_layout()
    Path(figure).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=150)
    plt.close(fig)


# ----------------------------------------------------------------------------- generic loop
def _save_checkpoint(path: Path, payload: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def _fit(stage: _Stage, hyper: dict, seed: int, fingerprint: str, model_path: str, losses: str,
         figure: str, checkpoint: str | None, info: dict, max_epochs_this_run: int | None,
         checkpoint_every: int, progress: bool) -> dict:
    """Train ``stage.model`` (already seeded, built and on the device); see module docstring."""
    from tqdm import tqdm

    device = stage.device
    model = stage.model
    params = [p for p in model.parameters() if p.requires_grad]
    opt = make_optimizer(params, float(hyper["lr"]), float(hyper["weight_decay"]), device)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=int(hyper["lr_step"]), gamma=float(hyper["lr_gamma"]))
    gen = torch.Generator().manual_seed(derived_seed(seed, 1))
    epochs, bs = int(hyper["epochs"]), int(hyper["batch_size"])
    clip = float(hyper["grad_clip"])
    ckpt_path = Path(checkpoint) if checkpoint else Path(str(model_path) + ".ckpt")
    losses_path = Path(losses)
    columns = _columns(stage)

    history: list[dict] = []
    start = 0
    if ckpt_path.exists():
        try:
            ck = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        except Exception as exc:  # unreadable (e.g. truncated) checkpoint: start over
            log.warning("ignoring unreadable checkpoint %s (%s)", ckpt_path, exc)
            ck = None
        if ck is not None and ck.get("fingerprint") == fingerprint:
            model.load_state_dict(ck["model"])
            opt.load_state_dict(ck["optimizer"])
            sched.load_state_dict(ck["scheduler"])
            gen.set_state(ck["generator"])
            torch.set_rng_state(ck["torch_rng"])
            history, start = list(ck["history"]), int(ck["epoch"])
            log.info("%s: resuming from %s at epoch %d/%d", stage.name, ckpt_path, start, epochs)
        elif ck is not None:
            log.warning("%s: checkpoint %s is from a different run; starting over", stage.name, ckpt_path)
    _write_rows(losses_path, columns, history, "w")

    def save_ckpt(epoch: int) -> None:
        _save_checkpoint(ckpt_path, {
            "fingerprint": fingerprint, "epoch": epoch, "model": model.state_dict(),
            "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "generator": gen.get_state(), "torch_rng": torch.get_rng_state(), "history": history,
        })

    stop = epochs if max_epochs_this_run is None else min(epochs, start + int(max_epochs_this_run))
    n = stage.n_train
    n_full = (n // bs) * bs
    bounds = [(b, min(n, b + bs)) for b in range(0, n, bs) if min(n, b + bs) - b >= 2 or b < n_full]
    bar = tqdm(total=epochs, initial=start, desc=stage.name, file=sys.stderr, disable=not progress,
               dynamic_ncols=True, mininterval=1.0)
    for epoch in range(start, stop):
        t0 = time.perf_counter()
        model.train()
        stage.begin_epoch(gen)
        perm = torch.randperm(n, generator=gen).to(device)
        lr = opt.param_groups[0]["lr"]
        acc = torch.zeros((), device=device, dtype=torch.float64)
        acc_parts = {p: torch.zeros((), device=device, dtype=torch.float64) for p in stage.parts}
        used = 0
        for b0, b1 in bounds:
            idx = perm[b0:b1]
            loss, parts = stage.batch_loss(idx)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if clip > 0:
                nn.utils.clip_grad_norm_(params, clip)
            opt.step()
            k = b1 - b0
            acc += loss.detach().double() * k
            for p in stage.parts:
                acc_parts[p] += parts[p].double() * k
            used += k
        sched.step()
        model.eval()
        test_loss, test_parts = stage.evaluate()
        row = {"epoch": epoch + 1, "train_loss": float(acc) / used, "test_loss": test_loss, "lr": lr,
               "seconds": time.perf_counter() - t0}
        for p in stage.parts:
            row[f"train_{p}"] = float(acc_parts[p]) / used
            row[f"test_{p}"] = test_parts[p]
        history.append(row)
        _write_rows(losses_path, columns, [row], "a")
        if not (math.isfinite(row["train_loss"]) and math.isfinite(row["test_loss"])):
            bar.close()
            save_ckpt(epoch + 1)
            raise FloatingPointError(f"{stage.name}: non-finite loss at epoch {epoch + 1}: {row}")
        bar.update(1)
        bar.set_postfix_str(f"train={row['train_loss']:.4g} test={test_loss:.4g} lr={lr:.3g}", refresh=False)
        if (epoch + 1) % checkpoint_every == 0 and epoch + 1 < stop:
            save_ckpt(epoch + 1)
    bar.close()
    done = len(history)
    save_ckpt(done)
    result = {"completed": done >= epochs, "epochs_done": done,
              "train_loss": history[-1]["train_loss"] if history else None,
              "test_loss": history[-1]["test_loss"] if history else None}
    if not result["completed"]:
        return result
    model.eval()
    info = {**info, "epochs_done": done, "final_train_loss": result["train_loss"],
            "final_test_loss": result["test_loss"], "device": str(device), "torch": str(torch.__version__)}
    nw.save_model(model, model_path, info=info)
    ylabel = {"emulator": "MSE (standardized outputs)", "flow": "negative log-likelihood (nats)",
              "encoder_decoder": "weighted total loss"}.get(stage.name, "loss")
    plot_losses(losses_path, figure, title=f"{stage.name} ({info.get('label', '')})".replace(" ()", ""), ylabel=ylabel)
    return result


def _setup(stage: str, hyper: dict, device: str, threads: int) -> tuple[dict, torch.device]:
    h = check_hyper(stage, hyper)
    torch.set_num_threads(int(threads))
    return h, resolve_device(device)


def _fingerprint(**items) -> str:
    return hashlib.sha256(json.dumps(items, sort_keys=True, default=str).encode()).hexdigest()


# ----------------------------------------------------------------------------- entry points
def train_emulator(train: str, test: str, model: str, losses: str, figure: str, hyper: dict, seed: int,
                   device: str = "auto", threads: int = 1, checkpoint: str | None = None,
                   max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                   progress: bool = True) -> dict:
    """Train ``NN_e`` (parameters -> outputs) on clean data; write ``model`` (.pt), ``losses``
    (CSV) and ``figure`` (PNG). ``max_epochs_this_run`` stops early after that many epochs of
    this call (checkpoint only, no model written). Returns a summary dict (``completed``,
    ``epochs_done``, ``train_loss``, ``test_loss``)."""
    h, dev = _setup("emulator", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)
    torch.manual_seed(seed)
    net = nw.Emulator(h["hidden"], h["layers"], activation=h["activation"])
    net.x_scaler.fit(v_tr)
    net.y_scaler.fit(y_tr)
    net.to(dev)
    st = EmulatorStage(net, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                       net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), dev)
    fp = _fingerprint(stage="emulator", hyper=h, seed=seed, data=_digest(v_tr, y_tr, v_te, y_te), fmt=nw.FORMAT)
    info = {"stage": "emulator", "hyper": h, "seed": seed, "noise_level": 0.0, "n_train": len(v_tr), "n_test": len(v_te)}
    return _fit(st, h, seed, fp, model, losses, figure, checkpoint, info, max_epochs_this_run, checkpoint_every, progress)


def train_flow(train: str, test: str, model: str, losses: str, figure: str, hyper: dict, seed: int,
               noise_level: float = 0.0, device: str = "auto", threads: int = 1, checkpoint: str | None = None,
               max_epochs_this_run: int | None = None, checkpoint_every: int = 50, progress: bool = True) -> dict:
    """Train the Real-NVP ``NN_f`` on the outputs with training noise of level ``noise_level``
    (delta, multiplier of the registry noise std). Outputs and return value as
    :func:`train_emulator`."""
    h, dev = _setup("flow", hyper, device, threads)
    _, y_tr = load_split(train)
    _, y_te = load_split(test)
    torch.manual_seed(seed)
    net = nw.RealNVP(hidden=h["hidden"], blocks=h["blocks"], layers_per_block=h["layers_per_block"],
                     batchnorm=bool(h["batchnorm"]))
    net.y_scaler.fit(y_tr)
    net.to(dev)
    test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
    st = FlowStage(net, net.y_scaler.transform(y_tr), net.y_scaler.transform(y_te), noise_level, test_gen, dev)
    fp = _fingerprint(stage="flow", hyper=h, seed=seed, noise=float(noise_level), data=_digest(y_tr, y_te),
                      noise_std=noise_std().tolist(), fmt=nw.FORMAT)
    info = {"stage": "flow", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(y_tr), "n_test": len(y_te), "label": f"delta={noise_level:g}"}
    return _fit(st, h, seed, fp, model, losses, figure, checkpoint, info, max_epochs_this_run, checkpoint_every, progress)


def train_encoder_decoder(train: str, test: str, emulator: str, model: str, losses: str, figure: str,
                          hyper: dict, seed: int, noise_level: float = 0.0, device: str = "auto",
                          threads: int = 1, checkpoint: str | None = None,
                          max_epochs_this_run: int | None = None, checkpoint_every: int = 50,
                          progress: bool = True) -> dict:
    """Train ``NN_v`` + ``NN_d`` with the re-evaluation term through the frozen emulator file
    ``emulator``; training noise of level ``noise_level`` on y' everywhere. Outputs and return
    value as :func:`train_emulator`."""
    h, dev = _setup("encoder_decoder", hyper, device, threads)
    v_tr, y_tr = load_split(train)
    v_te, y_te = load_split(test)
    emu = nw.load_model(emulator, map_location=dev)
    if not isinstance(emu, nw.Emulator):
        raise ValueError(f"{emulator}: expected an emulator model, got {type(emu).__name__}")
    emu.eval().requires_grad_(False)
    torch.manual_seed(seed)
    net = nw.EncoderDecoder(latent_dim=h["latent_dim"], encoder_hidden=h["encoder_hidden"],
                            encoder_layers=h["encoder_layers"], decoder_hidden=h["decoder_hidden"],
                            decoder_layers=h["decoder_layers"], activation=h["activation"])
    net.x_scaler.fit(v_tr)
    net.y_scaler.fit(y_tr)
    net.to(dev)
    test_gen = torch.Generator().manual_seed(derived_seed(seed, 2))
    st = EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                             net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), noise_level, h,
                             test_gen, dev)
    fp = _fingerprint(stage="encoder_decoder", hyper=h, seed=seed, noise=float(noise_level),
                      data=_digest(v_tr, y_tr, v_te, y_te), emulator=_file_digest(emulator),
                      noise_std=noise_std().tolist(), fmt=nw.FORMAT)
    info = {"stage": "encoder_decoder", "hyper": h, "seed": seed, "noise_level": float(noise_level),
            "n_train": len(v_tr), "n_test": len(v_te), "label": f"delta={noise_level:g}"}
    return _fit(st, h, seed, fp, model, losses, figure, checkpoint, info, max_epochs_this_run, checkpoint_every, progress)
