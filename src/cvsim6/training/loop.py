"""The epoch loop of one training run: minibatch steps, test evaluations, the losses CSV,
checkpoints and the saved model.

* Randomness: the stage's model is built after ``torch.manual_seed`` (initial weights); one CPU
  ``torch.Generator`` (seed ``derived_seed(seed, 1)``) draws, per epoch and in this order, the
  stage's random inputs (:meth:`Stage.begin_epoch`) and the minibatch permutation. Results are
  bit-reproducible on CPU for a fixed thread count.
* Minibatches: whole tensors on the device, indexed by a permutation; a trailing batch of a
  single sample is dropped (BatchNorm needs two). Adam (``fused=True`` when supported) and the
  learning-rate schedule stepped once per epoch (:mod:`cvsim6.training.optimization`).
* Losses CSV columns: ``epoch`` (1-based), ``train_loss`` (sample-weighted mean over the
  epoch's minibatches, in train mode), ``test_loss`` (eval mode, full test split; NaN in epochs
  not evaluated), ``lr`` (learning rate used in that epoch), ``seconds`` and ``cpu_seconds``
  (wall and process CPU time of that epoch; the model file holds no timings, so it is
  bit-reproducible), then ``train_<part>``/``test_<part>`` per loss term of the stage, then
  ``skipped_steps`` when ``grad_clip`` is on.
* Checkpoints (model, optimizer, scheduler, RNG states, history, epoch) every
  ``checkpoint_every`` epochs and at the end, written atomically to ``checkpoint`` (default
  ``model + ".ckpt"``). A rerun with the same arguments resumes from it and yields the same
  final weights as an uninterrupted run; a checkpoint of another run (its fingerprint,
  :mod:`cvsim6.training.fingerprint`) is ignored and overwritten. A non-finite loss ends the
  run with ``FloatingPointError``; the last good checkpoint stays, the failed state goes to
  ``<checkpoint>.nonfinite`` for inspection.
"""
from __future__ import annotations

import csv
import logging
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from cvsim6 import nets as nw
from cvsim6.seeding import derived_seed
from cvsim6.training.optimization import make_optimizer, make_scheduler
from cvsim6.training.stages import Stage

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- losses CSV
def loss_columns(stage: Stage, grad_clip: float = 0.0) -> list[str]:
    """Losses-CSV columns: ``skipped_steps`` last when the gradient guard is on."""
    cols = ["epoch", "train_loss", "test_loss", "lr", "seconds", "cpu_seconds"]
    cols += [f"train_{p}" for p in stage.parts] + [f"test_{p}" for p in stage.parts]
    return cols + (["skipped_steps"] if grad_clip > 0 else [])


def write_loss_rows(path: Path, columns: list[str], rows: list[dict], mode: str) -> None:
    """Write (``mode`` "w", with the header) or append (``"a"``) ``rows`` to the CSV at ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, mode, newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        if mode == "w":
            w.writeheader()
        for r in rows:  # a column the row lacks (a checkpoint of an older version) stays empty
            w.writerow({k: ("" if k not in r else int(r[k]) if k in ("epoch", "skipped_steps") else repr(float(r[k])))
                        for k in columns})


# ----------------------------------------------------------------------------- checkpoints
def read_checkpoint(path: Path) -> dict | None:
    """The checkpoint at ``path``, or None when there is none or it is unreadable (e.g.
    truncated: logged, and the run starts over)."""
    if not path.exists():
        return None
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        log.warning("ignoring unreadable checkpoint %s (%s)", path, exc)
        return None


def save_checkpoint(path: Path, payload: dict) -> None:
    """``torch.save`` ``payload`` to ``path`` atomically (temporary file + rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


@dataclass
class _RunState:
    """What a checkpoint holds of a run besides its fingerprint and epoch."""

    model: nn.Module
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LRScheduler
    gen: torch.Generator
    history: list
    best: dict
    extra: dict | None

    def payload(self, fingerprint: str, epoch: int) -> dict:
        """The checkpoint of this state after ``epoch`` epochs."""
        return {
            "fingerprint": fingerprint, "epoch": epoch, "model": self.model.state_dict(),
            "optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(),
            "generator": self.gen.get_state(), "torch_rng": torch.get_rng_state(), "history": self.history,
            "best": self.best, "extra": self.extra or {},
        }


def _resume(st: _RunState, ckpt_path: Path, fingerprint: str, stage_name: str, epochs: int) -> int:
    """Load the checkpoint at ``ckpt_path`` into ``st`` when it is of this run; the epochs
    already done (0 when starting over)."""
    ck = read_checkpoint(ckpt_path)
    if ck is None:
        return 0
    if ck.get("fingerprint") != fingerprint:
        log.warning("%s: checkpoint %s is from a different run; starting over", stage_name, ckpt_path)
        return 0
    st.model.load_state_dict(ck["model"])
    st.opt.load_state_dict(ck["optimizer"])
    st.sched.load_state_dict(ck["scheduler"])
    st.gen.set_state(ck["generator"])
    torch.set_rng_state(ck["torch_rng"])
    st.history, start = list(ck["history"]), int(ck["epoch"])
    st.best = ck.get("best", st.best)
    st.extra = ck.get("extra") or st.extra
    log.info("%s: resuming from %s at epoch %d/%d", stage_name, ckpt_path, start, epochs)
    return start


# ----------------------------------------------------------------------------- one epoch
def batch_bounds(n: int, batch_size: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the minibatches of ``n`` rows: a trailing batch of one row is dropped."""
    n_full = (n // batch_size) * batch_size
    return [(b, min(n, b + batch_size)) for b in range(0, n, batch_size)
            if min(n, b + batch_size) - b >= 2 or b < n_full]


def _steps(stage: Stage, st: _RunState, params: list, perm: torch.Tensor, bounds: list, clip: float):
    """The optimizer steps of one epoch: the sample-weighted sums of the loss and its parts,
    the rows they cover and the steps skipped for a non-finite gradient norm."""
    device = stage.device
    acc = torch.zeros((), device=device, dtype=torch.float64)
    acc_parts = {p: torch.zeros((), device=device, dtype=torch.float64) for p in stage.parts}
    used = skipped = 0
    for b0, b1 in bounds:
        idx = perm[b0:b1]
        loss, parts = stage.batch_loss(idx)
        st.opt.zero_grad(set_to_none=True)
        loss.backward()
        if clip > 0:
            norm = nn.utils.get_total_norm([p.grad for p in params if p.grad is not None])
            if not torch.isfinite(norm):  # overflowed (a loss spike): no update, out of the mean
                skipped += 1
                continue
            if norm > clip:  # else the gradient is left untouched, bit for bit
                nn.utils.clip_grads_with_norm_(params, clip, norm)
        st.opt.step()
        k = b1 - b0
        acc += loss.detach().double() * k
        for p in stage.parts:
            acc_parts[p] += parts[p].double() * k
        used += k
    return acc, acc_parts, used, skipped


def _epoch(stage: Stage, st: _RunState, params: list, bounds: list, hyper: dict,
           epoch: int) -> tuple[dict, bool]:
    """Train epoch ``epoch`` (0-based), step the schedule, evaluate when due: its losses-CSV row
    without the timings, and whether the test loss was evaluated."""
    clip, epochs = float(hyper["grad_clip"]), int(hyper["epochs"])
    st.model.train()
    stage.begin_epoch(st.gen, epoch)
    perm = torch.randperm(stage.n_train, generator=st.gen).to(stage.device)
    lr = st.opt.param_groups[0]["lr"]
    acc, acc_parts, used, skipped = _steps(stage, st, params, perm, bounds, clip)
    st.sched.step()
    st.model.eval()
    evaluated = (epoch + 1) % int(hyper["eval_every"]) == 0 or epoch + 1 == epochs
    test_loss, test_parts = stage.evaluate() if evaluated else (math.nan, {})
    row = {"epoch": epoch + 1, "train_loss": float(acc) / used if used else math.nan, "test_loss": test_loss,
           "lr": lr}
    if clip > 0:
        row["skipped_steps"] = skipped
        if skipped:
            log.warning("%s: epoch %d: %d of %d steps skipped (non-finite gradient norm)", stage.name,
                        epoch + 1, skipped, len(bounds))
    for p in stage.parts:
        row[f"train_{p}"] = float(acc_parts[p]) / used if used else math.nan
        row[f"test_{p}"] = test_parts.get(p, math.nan)
    return row, evaluated


# ----------------------------------------------------------------------------- the run
def fit(stage: Stage, hyper: dict, seed: int, fingerprint: str, model_path: str, losses: str,
        checkpoint: str | None, info: dict, max_epochs_this_run: int | None,
        checkpoint_every: int, progress: bool, max_cpu_seconds: float | None = None,
        until_epoch: int | None = None, extra: dict | None = None) -> dict:
    """Train ``stage.model`` (already seeded, built and on the device); see the module docstring.
    ``max_cpu_seconds`` (benchmarks) stops after the epoch in which the run's CPU time, summed
    over epochs, reaches it (checkpoint only, as ``max_epochs_this_run``); ``until_epoch`` stops
    after that epoch of the schedule (restart candidates). ``extra`` (JSON-able dict) is kept in
    the checkpoint, restored from it on resume, and added to the saved model's ``info``."""
    from tqdm import tqdm

    model = stage.model
    params = [p for p in model.parameters() if p.requires_grad]
    opt = make_optimizer(params, float(hyper["lr"]), float(hyper["weight_decay"]), stage.device)
    st = _RunState(model, opt, make_scheduler(opt, hyper), torch.Generator().manual_seed(derived_seed(seed, 1)),
                   [], {"loss": math.inf, "epoch": 0, "model": None}, extra)
    epochs, keep_best = int(hyper["epochs"]), bool(hyper["keep_best"])
    ckpt_path = Path(checkpoint) if checkpoint else Path(str(model_path) + ".ckpt")
    losses_path, columns = Path(losses), loss_columns(stage, float(hyper["grad_clip"]))
    start = _resume(st, ckpt_path, fingerprint, stage.name, epochs)
    write_loss_rows(losses_path, columns, st.history, "w")

    stop = epochs if max_epochs_this_run is None else min(epochs, start + int(max_epochs_this_run))
    if until_epoch is not None:
        stop = min(stop, int(until_epoch))
    bounds = batch_bounds(stage.n_train, int(hyper["batch_size"]))
    bar = tqdm(total=epochs, initial=start, desc=stage.name, file=sys.stderr, disable=not progress,
               dynamic_ncols=True, mininterval=1.0)
    cpu_used = sum(r["cpu_seconds"] for r in st.history)
    for epoch in range(start, stop):
        t0, c0 = time.perf_counter(), time.process_time()
        row, evaluated = _epoch(stage, st, params, bounds, hyper, epoch)
        test_loss = row["test_loss"]
        if keep_best and evaluated and test_loss < st.best["loss"]:
            st.best = {"loss": test_loss, "epoch": epoch + 1,
                       "model": {k: v.detach().clone() for k, v in model.state_dict().items()}}
        row["seconds"], row["cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
        cpu_used += row["cpu_seconds"]
        st.history.append(row)
        write_loss_rows(losses_path, columns, [row], "a")
        if not (math.isfinite(row["train_loss"]) and (math.isfinite(test_loss) or not evaluated)):
            bar.close()  # the last good checkpoint stays; the failed state is kept beside it
            failed = ckpt_path.with_name(ckpt_path.name + ".nonfinite")
            save_checkpoint(failed, st.payload(fingerprint, epoch + 1))
            raise FloatingPointError(f"{stage.name}: non-finite loss at epoch {epoch + 1} (its state: {failed}): {row}")
        bar.update(1)
        bar.set_postfix_str(f"train={row['train_loss']:.4g} test={test_loss:.4g} lr={row['lr']:.3g}", refresh=False)
        if (epoch + 1) % checkpoint_every == 0 and epoch + 1 < stop:
            save_checkpoint(ckpt_path, st.payload(fingerprint, epoch + 1))
        if max_cpu_seconds is not None and cpu_used >= max_cpu_seconds:
            break
    bar.close()
    save_checkpoint(ckpt_path, st.payload(fingerprint, len(st.history)))
    return _finish(stage, st, hyper, start, cpu_used, model_path, info)


def _finish(stage: Stage, st: _RunState, hyper: dict, start: int, cpu_used: float, model_path: str,
            info: dict) -> dict:
    """The run's summary; when the schedule is complete, the model (best or last weights, per
    ``keep_best``) saved to ``model_path`` with ``info`` and the training record."""
    done, epochs, keep_best = len(st.history), int(hyper["epochs"]), bool(hyper["keep_best"])
    tested = [r for r in st.history if math.isfinite(r["test_loss"])]
    result = {"completed": done >= epochs, "epochs_done": done, "epochs_this_run": done - start,
              "cpu_seconds": cpu_used,
              "train_loss": st.history[-1]["train_loss"] if st.history else None,
              "test_loss": tested[-1]["test_loss"] if tested else None}
    if not result["completed"]:
        return result
    if keep_best and st.best["model"] is not None:
        st.model.load_state_dict(st.best["model"])
        result["test_loss"] = st.best["loss"]
    st.model.eval()
    info = {**info, **(st.extra or {}), "epochs_done": done, "final_train_loss": result["train_loss"],
            "final_test_loss": result["test_loss"], "best_epoch": st.best["epoch"] if keep_best else done,
            "device": str(stage.device), "torch": str(torch.__version__)}
    nw.save_model(st.model, model_path, info=info)
    return result
