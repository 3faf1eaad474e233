"""Best of ``restarts`` initializations: each candidate trains the first ``restart_epochs``
epochs of the schedule, the one with the lowest test loss there trains on
(:func:`train_with_restarts`). With a ``restart_target``, candidates are screened further, up to
``max_restarts``, until one has found every latent direction (:func:`choose_candidate`)."""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from pathlib import Path

import torch

from cvsim6.seeding import candidate_seed
from cvsim6.training import loop
from cvsim6.training.stages import Stage

log = logging.getLogger(__name__)


def _candidate_path(ckpt: Path, candidate: int) -> Path:
    """Default checkpoint of restart candidate ``candidate`` beside the run's ``ckpt``."""
    return ckpt.with_name(f"{ckpt.name}.candidate{candidate}")


def _candidate_score(path: Path, fingerprint: str, restart_epochs: int) -> float | None:
    """Test loss of a finished restart candidate (its checkpoint at ``path``): the one at epoch
    ``restart_epochs``, ``inf`` for a candidate that diverged; ``None`` when it has still to (finish
    its) training. Reads only: a candidate trained by a job of its own is an input of the run."""
    ck = loop.read_checkpoint(path)
    if ck is None or ck.get("fingerprint") != fingerprint:
        return None
    if ck.get("diverged"):
        return math.inf
    if int(ck["epoch"]) < restart_epochs:
        return None
    return float(next(row["test_loss"] for row in ck["history"] if int(row["epoch"]) == restart_epochs))


def worst_reconstruction(make_stage: Callable[[int], Stage], seed: int, c: int, path: Path) -> float:
    """The largest per-parameter reconstruction MSE (:meth:`~cvsim6.training.stages.EncoderDecoderStage.reconstruction_errors`)
    of restart candidate ``c`` at its checkpoint ``path``; ``inf`` for a candidate that diverged."""
    ck = loop.read_checkpoint(path)
    if ck is None or ck.get("diverged"):
        return math.inf
    stage = make_stage(candidate_seed(seed, c))
    stage.model.load_state_dict(ck["model"])
    stage.model.eval()
    return float(stage.reconstruction_errors().max())


def meets_target(worst: list[float | None], target: float | None) -> bool:
    """Whether a candidate's worst reconstruction MSE is at most ``target`` (never when None)."""
    return target is not None and any(w is not None and w <= target for w in worst)


def choose_candidate(test_loss: list[float], worst: list[float | None], target: float | None) -> int:
    """The candidate to continue: the lowest test loss among those whose worst reconstruction
    MSE is at most ``target`` (all of them when ``target`` is None or none is); ties to the lower
    index, a diverged one (``inf``) only when all did."""
    ok = [c for c, w in enumerate(worst) if meets_target([w], target)]
    pool = ok or list(range(len(test_loss)))
    return min(pool, key=lambda c: (test_loss[c], c))


def _run_candidate(make_stage: Callable[[int], Stage], hyper: dict, seed: int, fingerprint: str, c: int,
                   path: Path, model_path: str, info: dict, max_epochs_this_run: int | None, checkpoint_every: int,
                   progress: bool, max_cpu_seconds: float | None) -> dict:
    """Train restart candidate ``c`` to epoch ``restart_epochs`` (or resume it), checkpoint at
    ``path``, losses at ``path + ".csv"``. Returns :func:`~cvsim6.training.loop.fit`'s result
    with ``score`` (its test loss at the choice; ``inf`` when it diverged, recorded in its checkpoint so that no rerun
    replays it; ``None`` when stopped early by the budget)."""
    r = int(hyper["restart_epochs"])
    fp_c = f"{fingerprint}:candidate{c}"
    done = _candidate_score(path, fp_c, r)
    if done is not None:
        return {"completed": False, "epochs_done": r, "epochs_this_run": 0, "cpu_seconds": 0.0, "score": done}
    cseed = candidate_seed(seed, c)
    try:
        res = loop.fit(make_stage(cseed), hyper, cseed, fp_c, model_path, str(path) + ".csv", str(path), info,
                       max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds, until_epoch=r)
    except FloatingPointError as exc:  # a diverged candidate loses
        log.warning("%s: restart candidate %d diverged: %s", info.get("stage"), c, exc)
        loop.save_checkpoint(path, {"fingerprint": fp_c, "diverged": True, "error": str(exc)})
        return {"completed": False, "epochs_done": 0, "epochs_this_run": 0, "cpu_seconds": 0.0, "score": math.inf}
    score = float(res["test_loss"]) if res["epochs_done"] >= r else None  # evaluated at r (a multiple of eval_every)
    if score is not None:
        log.info("%s: restart candidate %d (seed %d): test loss %.6g at epoch %d", info.get("stage"), c, cseed,
                 score, r)
    return {**res, "score": score}


def train_with_restarts(make_stage: Callable[[int], Stage], hyper: dict, seed: int, fingerprint: str,
                        model_path: str, losses: str, checkpoint: str | None, info: dict,
                        max_epochs_this_run: int | None, checkpoint_every: int, progress: bool,
                        max_cpu_seconds: float | None, candidate: int | None = None,
                        candidates: list[str] | None = None) -> dict:
    """:func:`~cvsim6.training.loop.fit` with best-of-``restarts`` initializations.

    ``make_stage(init_seed)`` builds the stage with a model seeded by ``torch.manual_seed(init_seed)``
    (everything else, test noise included, from the master ``seed``). With ``restarts`` k > 1, k
    candidates (seeds :func:`cvsim6.seeding.candidate_seed`) each train the first ``restart_epochs`` epochs of the
    full schedule, exactly as they would alone, with their own checkpoint and losses CSV
    (``candidates[c]`` and ``candidates[c] + ".csv"``; by default ``<checkpoint>.candidate<c>``);
    the one with the lowest test loss at that epoch (the criterion of ``keep_best``; ties to the
    lower index; a diverged one loses) becomes the run's checkpoint and trains to the end. With
    ``restart_target`` (encoder/decoder), when no candidate's worst reconstruction MSE
    (:func:`worst_reconstruction`) is at most the target, this job trains candidates k, k + 1, ...
    one at a time until one is or ``max_restarts`` have trained, and the choice is among those that
    meet the target (:func:`choose_candidate`). Every
    phase resumes from its checkpoint; ``max_epochs_this_run`` and ``max_cpu_seconds`` count
    across the candidates. The model's ``info`` gets ``restart``: the candidates' seeds, test
    losses and worst reconstruction MSEs (None without a target), the target and the chosen index.

    ``candidate`` = c trains only candidate c, to the choice, at ``checkpoint`` (required) with its
    losses at ``losses`` (the workflow runs each candidate as a job of its own, side by side, and
    gives the run their checkpoints as ``candidates``: finished ones are read, not retrained).
    """
    k = int(hyper["restarts"])
    if candidate is not None:
        if k == 1 or not (int(candidate) == candidate and 0 <= candidate < k):
            raise ValueError(f"{info.get('stage')}: restart candidate {candidate!r} is not one of the {k} "
                             f"initializations (restarts: {k})")
        if not checkpoint or Path(losses) != Path(str(checkpoint) + ".csv"):
            raise ValueError(f"restart candidate {candidate}: give its checkpoint, with losses at checkpoint + '.csv' "
                             f"(got checkpoint={checkpoint!r}, losses={losses!r})")
        return _run_candidate(make_stage, hyper, seed, fingerprint, int(candidate), Path(checkpoint), model_path,
                              info, max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds)
    if k == 1:
        return loop.fit(make_stage(seed), hyper, seed, fingerprint, model_path, losses, checkpoint, info,
                        max_epochs_this_run, checkpoint_every, progress, max_cpu_seconds)
    ckpt = Path(checkpoint) if checkpoint else Path(str(model_path) + ".ckpt")
    paths = [Path(x) for x in candidates] if candidates else [_candidate_path(ckpt, c) for c in range(k)]
    if len(paths) != k:
        raise ValueError(f"{info.get('stage')}: {len(paths)} candidate checkpoints given for restarts: {k}")
    r = int(hyper["restart_epochs"])
    target = hyper.get("restart_target")
    n_max = max(k, int(hyper.get("max_restarts") or k))
    paths += [_candidate_path(ckpt, c) for c in range(k, n_max)]  # screened by this job, one at a time
    budget, cpu_left = max_epochs_this_run, max_cpu_seconds
    if (loop.read_checkpoint(ckpt) or {}).get("fingerprint") != fingerprint:
        scores: list[float] = []
        worst: list[float | None] = []
        for c, path in enumerate(paths):
            if c >= k and meets_target(worst, target):
                break  # a screened candidate has found every direction
            res = _run_candidate(make_stage, hyper, seed, fingerprint, c, path, model_path, info, budget,
                                 checkpoint_every, progress, cpu_left)
            if budget is not None:
                budget -= res["epochs_this_run"]
            if cpu_left is not None:
                cpu_left -= res["cpu_seconds"]
            if res["score"] is None:  # stopped by the budget: resume later
                return {**res, "completed": False}
            scores.append(res["score"])
            worst.append(None if target is None else worst_reconstruction(make_stage, seed, c, path))
            if worst[-1] is not None:
                log.info("%s: restart candidate %d: worst parameter reconstruction MSE %.4g", info.get("stage"), c,
                         worst[-1])
        if not any(math.isfinite(x) for x in scores):
            raise FloatingPointError(f"{info.get('stage')}: all {len(scores)} restart candidates diverged")
        chosen = choose_candidate(scores, worst, target)
        log.info("%s: candidate %d chosen of %d", info.get("stage"), chosen, len(scores))
        ck = torch.load(paths[chosen], map_location="cpu", weights_only=True)
        ck["fingerprint"] = fingerprint
        ck["extra"] = {"restart": {"epochs": r, "chosen": chosen, "target": target,
                                   "seeds": [candidate_seed(seed, c) for c in range(len(scores))],
                                   "test_loss": scores, "worst_reconstruction": worst}}
        loop.save_checkpoint(ckpt, ck)
    # the run's checkpoint holds the chosen candidate: fit resumes it (its weights and streams)
    return loop.fit(make_stage(seed), hyper, seed, fingerprint, model_path, losses, checkpoint, info,
                    budget, checkpoint_every, progress, cpu_left)
