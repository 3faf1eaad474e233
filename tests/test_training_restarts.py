"""Training (cvsim6.training): restarts, the candidates' choice and the screening."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import torch

from cvsim6 import nets as nw
from cvsim6 import seeding
from cvsim6.data.datasets import load_split
from cvsim6.training import loop, restarts, stages
from cvsim6.training import hyperparameters as hp
from cvsim6.training import train as tr
from cvsim6.training.stages import EncoderDecoderStage

from conftest import ROOT
from training_helpers import ENCDEC, assert_same_weights, RESTARTS, encdec_run, drop_timing, SCREEN


def test_restarts_continue_the_candidate_with_the_lowest_test_loss(data, emulator, tmp_path):
    assert encdec_run(data, emulator, tmp_path / "r", RESTARTS)["completed"]
    info = torch.load(tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]
    seeds = [seeding.candidate_seed(3, c) for c in range(3)]
    assert info["seeds"] == seeds and seeds[0] == 3 and len(set(seeds)) == 3 and info["epochs"] == 2
    # each candidate's own losses file holds the score it was chosen by
    cand = [pd.read_csv(tmp_path / "r" / f"m.pt.ckpt.candidate{c}.csv") for c in range(3)]
    assert [df["epoch"].tolist() for df in cand] == [[1, 2]] * 3
    assert info["test_loss"] == [float(df["test_loss"].iloc[-1]) for df in cand]
    assert len(set(info["test_loss"])) == 3  # different initializations
    assert info["chosen"] == int(np.argmin(info["test_loss"]))
    # the run's history starts with the chosen candidate's epochs and goes on to the end
    run = pd.read_csv(tmp_path / "r" / "m.csv")
    assert run["epoch"].tolist() == list(range(1, 7))
    pd.testing.assert_frame_equal(drop_timing(run.iloc[:2]), drop_timing(cand[info["chosen"]]))
    # candidate 0 is the run without restarts, stopped at the choice
    encdec_run(data, emulator, tmp_path / "plain", {"epochs": 6}, max_epochs_this_run=2)
    a = torch.load(tmp_path / "plain" / "m.pt.ckpt", weights_only=True)["model"]
    b = torch.load(tmp_path / "r" / "m.pt.ckpt.candidate0", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)

    # interrupted during the second candidate, then rerun: the same choice and weights
    part = encdec_run(data, emulator, tmp_path / "split", RESTARTS, max_epochs_this_run=3)
    assert not part["completed"] and not (tmp_path / "split" / "m.pt.ckpt").exists()
    assert torch.load(tmp_path / "split" / "m.pt.ckpt.candidate1", weights_only=True)["epoch"] == 1
    assert encdec_run(data, emulator, tmp_path / "split", RESTARTS)["completed"]
    assert_same_weights(tmp_path / "r" / "m.pt", tmp_path / "split" / "m.pt")
    assert torch.load(tmp_path / "split" / "m.pt", weights_only=True)["info"]["restart"] == info


def _candidate_job(data, emulator, d, c, **kw):
    """Candidate ``c`` as the workflow's job of its own trains it: its checkpoint and losses given."""
    d.mkdir(exist_ok=True)
    ckpt = d / f"m.pt.ckpt.candidate{c}"
    return tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                                    model=str(d / "m.pt"), losses=f"{ckpt}.csv", checkpoint=str(ckpt),
                                    hyper=ENCDEC | RESTARTS, seed=3, noise_level=0.25, device="cpu",
                                    progress=False, checkpoint_every=2, candidate=c, **kw)


def test_candidates_trained_as_jobs_of_their_own_give_the_same_run_and_are_only_read(data, emulator, tmp_path):
    """The workflow trains each restart candidate in a job of its own, side by side, and hands the
    run their checkpoints: the run is bit-identical to one that trains them itself, and leaves
    its inputs (the candidates' files) untouched."""
    assert encdec_run(data, emulator, tmp_path / "r", RESTARTS)["completed"]
    jobs = tmp_path / "jobs"
    for c in (2, 0, 1):  # any order
        res = _candidate_job(data, emulator, jobs, c)
        assert res["epochs_done"] == 2 and not (jobs / "m.pt").exists() and not (jobs / "m.pt.ckpt").exists()
        assert res["score"] == float(pd.read_csv(f"{jobs}/m.pt.ckpt.candidate{c}.csv")["test_loss"].iloc[-1])
    files = sorted(jobs.iterdir())
    before = {f: (f.stat().st_mtime_ns, f.read_bytes()) for f in files}
    again = _candidate_job(data, emulator, jobs, 1)  # a finished candidate is not retrained
    assert again["epochs_this_run"] == 0 and again["score"] == torch.load(
        tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]["test_loss"][1]
    assert encdec_run(data, emulator, jobs, RESTARTS,
                       candidates=[str(jobs / f"m.pt.ckpt.candidate{c}") for c in range(3)])["completed"]
    assert {f: (f.stat().st_mtime_ns, f.read_bytes()) for f in files} == before
    assert_same_weights(tmp_path / "r" / "m.pt", jobs / "m.pt")
    info = [torch.load(d / "m.pt", weights_only=True)["info"]["restart"] for d in (tmp_path / "r", jobs)]
    assert info[0] == info[1]
    pd.testing.assert_frame_equal(drop_timing(pd.read_csv(tmp_path / "r" / "m.csv")),
                                  drop_timing(pd.read_csv(jobs / "m.csv")))


def test_a_candidate_continued_under_a_shorter_schedule_resumes_at_the_choice(data, emulator, tmp_path):
    """benchmarks/continuation_epochs.py: the chosen candidate's checkpoint, given the fingerprint
    of a run with fewer epochs (:func:`~cvsim6.training.train.encoder_decoder_fingerprint`, the
    one that run's checkpoints hold), is resumed at the choice epoch and trained to the end."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("continuation_epochs", ROOT / "benchmarks" / "continuation_epochs.py")
    ce = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ce)
    hyper = ENCDEC | RESTARTS | {"epochs": 8, "lr_schedule": "cosine", "warmup_epochs": 0, "lr_final": 0.1}
    d = tmp_path / "run"
    d.mkdir()
    ckpt = d / "m.pt.ckpt.candidate1"
    tr.train_encoder_decoder(str(data[0]), str(data[1]), emulator=str(emulator[0] / "emulator.pt"),
                             model=str(d / "m.pt"), losses=f"{ckpt}.csv", checkpoint=str(ckpt), hyper=hyper, seed=3, device="cpu",
                             progress=False, candidate=1)
    restart = {"chosen": 1, "epochs": 2}
    job = (5, tmp_path / "e5", data[0].parent, emulator[0] / "emulator.pt", hyper, 3, ckpt, restart)
    assert ce.continue_candidate(job)[0::2] == (5, 3)  # epochs 3-5 trained here
    out = tmp_path / "e5"
    losses = pd.read_csv(out / "encoder_decoder_delta0_losses.csv")
    assert losses["epoch"].tolist() == [1, 2, 3, 4, 5]
    pd.testing.assert_frame_equal(drop_timing(losses.iloc[:2]), drop_timing(pd.read_csv(f"{ckpt}.csv")))
    def cosine(epoch, total):  # warmup 0, lr_final 0.1 (optimization.make_scheduler)
        return hyper["lr"] * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * epoch / (total - 1))))

    # epoch 3 at the rate the 8-epoch cosine set after epoch 2 (restored with the optimizer), then the 5-epoch one
    assert losses["lr"].iloc[2:].tolist() == pytest.approx([cosine(2, 8), cosine(3, 5), cosine(4, 5)])
    assert losses["lr"].iloc[-1] == pytest.approx(0.1 * hyper["lr"])
    saved = torch.load(out / "models" / "encoder_decoder_delta0.pt", weights_only=True)["info"]
    assert saved["epochs_done"] == 5 and saved["restart"] == restart
    # the fingerprint is the one a 5-epoch run writes, and differs from the 8-epoch run's
    splits = (*load_split(str(data[0])), *load_split(str(data[1])))
    fp5 = tr.encoder_decoder_fingerprint(hp.check_hyper("encoder_decoder", hyper | {"epochs": 5}), 3, 0.0, splits,
                                         str(emulator[0] / "emulator.pt"))
    assert torch.load(out / "models" / "encoder_decoder_delta0.pt.ckpt", weights_only=True)["fingerprint"] == fp5
    assert torch.load(ckpt, weights_only=True)["fingerprint"].split(":")[0] != fp5
    assert ce.continue_candidate(job)[0::2] == (5, 0)  # a rerun reads the finished continuation


def test_candidate_options_are_checked(data, emulator, tmp_path):
    with pytest.raises(ValueError, match="candidate 3 is not one of the 3"):
        _candidate_job(data, emulator, tmp_path, 3)
    with pytest.raises(ValueError, match="candidate 0 is not one of the 1"):
        encdec_run(data, emulator, tmp_path, {"epochs": 6}, candidate=0, checkpoint=str(tmp_path / "c"))
    with pytest.raises(ValueError, match="losses at checkpoint"):
        encdec_run(data, emulator, tmp_path, RESTARTS, candidate=0, checkpoint=str(tmp_path / "c"))
    with pytest.raises(ValueError, match="2 candidate checkpoints given for restarts: 3"):
        encdec_run(data, emulator, tmp_path, RESTARTS, candidates=["a", "b"])
    assert not list(tmp_path.glob("*.ckpt*")) and not (tmp_path / "m.pt").exists()


def test_a_diverged_candidate_loses_and_is_not_replayed(data, emulator, tmp_path, monkeypatch):
    real_fit, calls = loop.fit, []

    def fit(stage, hyper, seed, *args, **kw):
        calls.append(seed)
        if seed == seeding.candidate_seed(3, 1):
            raise FloatingPointError("non-finite loss at epoch 1")
        return real_fit(stage, hyper, seed, *args, **kw)

    monkeypatch.setattr(loop, "fit", fit)
    res = encdec_run(data, emulator, tmp_path, RESTARTS, max_epochs_this_run=4)  # candidates 0, 2 to the choice
    assert not res["completed"] and calls == [seeding.candidate_seed(3, c) for c in range(3)] + [3]  # + the run, 0 epochs
    assert torch.load(tmp_path / "m.pt.ckpt.candidate1", weights_only=True)["diverged"]
    calls.clear()
    assert encdec_run(data, emulator, tmp_path, RESTARTS)["completed"]
    assert calls == [3]  # the run goes on from the chosen candidate; candidate 1 is not replayed
    info = torch.load(tmp_path / "m.pt", weights_only=True)["info"]["restart"]
    assert info["test_loss"][1] == float("inf") and info["chosen"] in (0, 2)
    assert info["chosen"] == (0 if info["test_loss"][0] <= info["test_loss"][2] else 2)


def test_restarts_that_tie_continue_candidate_0_exactly_as_a_run_without_them(data, emulator, tmp_path,
                                                                               monkeypatch):
    monkeypatch.setattr(restarts, "candidate_seed", lambda seed, c: seed)  # three identical candidates
    assert encdec_run(data, emulator, tmp_path / "r", RESTARTS)["completed"]
    info = torch.load(tmp_path / "r" / "m.pt", weights_only=True)["info"]["restart"]
    assert info["chosen"] == 0 and len(set(info["test_loss"])) == 1
    assert encdec_run(data, emulator, tmp_path / "plain", {"epochs": 6})["completed"]
    assert_same_weights(tmp_path / "plain" / "m.pt", tmp_path / "r" / "m.pt")
    pd.testing.assert_frame_equal(drop_timing(pd.read_csv(tmp_path / "plain" / "m.csv")),
                                  drop_timing(pd.read_csv(tmp_path / "r" / "m.csv")))


def test_choose_candidate_prefers_those_that_meet_the_target():
    loss = [3.0, 1.0, 2.0, 1.0]
    assert restarts.choose_candidate(loss, [None] * 4, None) == 1  # lowest loss, ties to the lower index
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.01, 0.02], None) == 1  # no target: loss only
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.01, 0.02], 0.05) == 3  # lowest loss among 2 and 3
    assert restarts.choose_candidate(loss, [0.01, 0.4, 0.5, 0.4], 0.05) == 0  # the only one, despite its loss
    assert restarts.choose_candidate(loss, [0.5, 0.4, 0.3, 0.2], 0.05) == 1  # none meets it: loss among all
    assert restarts.choose_candidate([math.inf, 2.0], [0.01, 0.5], 0.05) == 0  # inf worst: diverged never meets
    assert restarts.choose_candidate([math.inf, 2.0], [math.inf, 0.5], 0.05) == 1
    assert restarts.meets_target([None, 0.05], 0.05) and not restarts.meets_target([0.05], None)


def test_reconstruction_errors_of_a_decoder_that_returns_zero_are_the_test_parameters_second_moments(
        data, emulator, monkeypatch):
    """Per parameter, the mean over every test row (taken in chunks) of the squared standardized
    value, computed here by numpy from the parquet file and the fitted scaler."""
    monkeypatch.setattr(stages, "EVAL_CHUNK", 7)  # 100 test rows: 15 chunks, the last one short
    v_tr, y_tr = load_split(str(data[0]))
    v_te, y_te = load_split(str(data[1]))
    net = nw.EncoderDecoder(latent_dim=7, encoder_hidden=16, encoder_layers=3, decoder_hidden=32, decoder_layers=3)
    net.x_scaler.fit(v_tr)
    net.y_scaler.fit(y_tr)
    emu = nw.load_model(str(emulator[0] / "emulator.pt"))
    stage = EncoderDecoderStage(net, emu, net.x_scaler.transform(v_tr), net.y_scaler.transform(y_tr),
                                net.x_scaler.transform(v_te), net.y_scaler.transform(y_te), 0.25,
                                hp.check_hyper("encoder_decoder", ENCDEC), torch.Generator().manual_seed(0),
                                torch.device("cpu"))
    monkeypatch.setattr(net, "decode", lambda y, w: torch.zeros(len(y), 23, dtype=y.dtype))
    expected = (((v_te - net.x_scaler.mean.double().numpy()) / net.x_scaler.std.double().numpy()) ** 2).mean(axis=0)
    got = stage.reconstruction_errors().numpy()
    assert got.shape == (23,)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert (got > 0.5).all()  # test rows of the training range: each about its variance


def _screen(data, emulator, d, worst, monkeypatch, hyper=SCREEN, **kw):
    """A run whose candidate c has worst reconstruction MSE ``worst[c]`` (by design)."""
    calls = []

    def fake(make_stage, seed, c, path):
        calls.append(c)
        assert path.exists()
        return worst[c]

    monkeypatch.setattr(restarts, "worst_reconstruction", fake)
    res = encdec_run(data, emulator, d, hyper, **kw)
    if not res["completed"]:
        return None, calls
    return torch.load(d / "m.pt", weights_only=True)["info"]["restart"], calls


def test_screening_goes_on_until_a_candidate_meets_the_target(data, emulator, tmp_path, monkeypatch):
    info, calls = _screen(data, emulator, tmp_path / "met", [0.5, 0.4, 0.3, 0.6, 0.05, 0.01], monkeypatch)
    assert calls == [0, 1, 2, 3, 4]  # stops at the first that meets it: candidate 5 never trained
    assert not (tmp_path / "met" / "m.pt.ckpt.candidate5").exists()
    assert (tmp_path / "met" / "m.pt.ckpt.candidate4").exists()
    assert info["chosen"] == 4 and info["target"] == 0.1 and info["worst_reconstruction"] == [0.5, 0.4, 0.3, 0.6, 0.05]
    assert info["seeds"] == [seeding.candidate_seed(3, c) for c in range(5)] and len(info["test_loss"]) == 5
    # the run goes on from candidate 4: its history starts with that candidate's epochs
    run = pd.read_csv(tmp_path / "met" / "m.csv")
    cand = pd.read_csv(tmp_path / "met" / "m.pt.ckpt.candidate4.csv")
    pd.testing.assert_frame_equal(drop_timing(run.iloc[:2]), drop_timing(cand))
    # interrupted while screening candidate 4, then rerun: the same choice and weights
    worst = [0.5, 0.4, 0.3, 0.6, 0.05, 0.01]
    part, calls = _screen(data, emulator, tmp_path / "split", worst, monkeypatch, max_epochs_this_run=9)
    assert part is None and calls == [0, 1, 2, 3]
    assert torch.load(tmp_path / "split" / "m.pt.ckpt.candidate4", weights_only=True)["epoch"] == 1
    again, calls = _screen(data, emulator, tmp_path / "split", worst, monkeypatch)
    assert calls == [0, 1, 2, 3, 4] and again == info
    assert_same_weights(tmp_path / "met" / "m.pt", tmp_path / "split" / "m.pt")
    # none meets it: all max_restarts screened, the lowest test loss continues
    info, calls = _screen(data, emulator, tmp_path / "none", [0.5] * 6, monkeypatch)
    assert calls == list(range(6)) and info["chosen"] == int(np.argmin(info["test_loss"]))
    # one of the first restarts meets it: nothing more is screened, the choice as without a target
    info, calls = _screen(data, emulator, tmp_path / "first", [0.5, 0.01, 0.01, 0.0, 0.0, 0.0], monkeypatch)
    assert calls == [0, 1, 2] and len(info["test_loss"]) == 3
    losses = info["test_loss"]
    assert info["chosen"] == (1 if losses[1] <= losses[2] else 2)


