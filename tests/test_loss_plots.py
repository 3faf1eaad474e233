"""Loss figures (cvsim6.reporting.loss_figures): a divergence spike is cut from the axes and marked."""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from cvsim6.reporting import loss_figures as lp
from cvsim6 import nets as networks


def test_divergence_epochs_flags_a_spike_and_its_recovery_but_not_a_falling_or_rising_curve():
    epochs = np.arange(1, 1001)
    falling = 1.0 * np.exp(-epochs / 100.0) + 1e-6  # five decades down: the normal emulator shape
    assert not lp.divergence_epochs(falling).any()
    rising = 0.1 + 26.0 * (1.0 - np.exp(-epochs / 50.0))  # a KL term growing 2.4 decades from its start
    assert not lp.divergence_epochs(rising).any()
    spiked = falling.copy()
    spiked[600:650] = 1e15 * np.exp(-np.arange(50) / 2.0)  # blows up, then relearns
    flagged = lp.divergence_epochs(spiked)
    expected = spiked > 100.0 * np.minimum.accumulate(falling)
    assert flagged.sum() > 0 and np.array_equal(flagged, expected)
    assert flagged[600] and not flagged[:600].any() and not flagged[650:].any()
    with_gaps = spiked.copy()
    with_gaps[1::2] = np.nan  # a test loss evaluated every other epoch
    assert np.array_equal(lp.divergence_epochs(with_gaps), flagged & np.isfinite(with_gaps))
    assert not lp.divergence_epochs(np.r_[-5.0, 1e9]).any()  # a flow NLL: not on a log scale


def test_loss_figure_scales_to_the_healthy_epochs_and_marks_the_cut(tmp_path):
    epochs = np.arange(1, 2001)
    train = 2000.0 * np.exp(-epochs / 80.0) + 30.0
    train[1000:1100] = 5e15 * np.exp(-np.arange(100) / 4.0) + 30.0
    test = np.where(epochs % 10 == 0, train * 1.02, np.nan)
    df = pd.DataFrame(dict(epoch=epochs, train_loss=train, test_loss=test, train_kl=train / 2,
                           test_kl=test / 2, train_decoder=np.full(epochs.size, 0.01),
                           test_decoder=np.where(np.isnan(test), np.nan, 0.01)))
    df.to_csv(tmp_path / "l.csv", index=False)
    cuts = lp.plot_losses(tmp_path / "l.csv", tmp_path / "l.png")
    assert (tmp_path / "l.png").stat().st_size > 10_000
    spike = lp.divergence_epochs(train)
    healthy_max = max(np.nanmax(train[~spike]), np.nanmax(test[~spike]))
    assert healthy_max < cuts["loss"]["top"] < 2 * healthy_max  # the start of training stays in view
    assert cuts["loss"]["epochs"] == epochs[(train > cuts["loss"]["top"]) | (test > cuts["loss"]["top"])].tolist()
    assert cuts["loss"]["epochs"][0] == 1001 and cuts["loss"]["peak"] == pytest.approx(5e15, rel=1e-6)
    assert cuts["terms"]["epochs"][0] == 1001
    clean = df.copy()
    clean.loc[1000:1099, ["train_loss", "test_loss", "train_kl", "test_kl"]] = 40.0
    clean.to_csv(tmp_path / "c.csv", index=False)
    assert lp.plot_losses(tmp_path / "c.csv", tmp_path / "c.png") == {}
    # a guarded run (grad_clip) counts its skipped steps: those epochs are marked, nothing is cut
    clean["skipped_steps"] = 0
    clean.loc[[1750, 1900], "skipped_steps"] = [1, 2]
    clean.to_csv(tmp_path / "s.csv", index=False)
    assert lp.plot_losses(tmp_path / "s.csv", tmp_path / "s.png") == {"skipped": [1751, 1901]}
    clean["skipped_steps"] = 0
    clean.to_csv(tmp_path / "n.csv", index=False)
    assert lp.plot_losses(tmp_path / "n.csv", tmp_path / "n.png") == {}


def test_cut_label_names_one_epoch_or_the_range():
    assert lp.cut_label(np.array([2262]), 3.0e14) == "epoch 2262 above the axis (peak 3e+14)"
    assert lp.cut_label(np.array([1001, 1002, 1050]), 5e15) == "3 epochs above the axis (epochs 1001-1050, peak 5e+15)"


def _emulator_csv(path, mse_columns: bool):
    epochs = np.arange(1, 101)
    loss = np.exp(-epochs / 20.0)
    df = pd.DataFrame(dict(epoch=epochs, train_loss=loss, test_loss=loss * 1.1, lr=1e-3))
    if mse_columns:
        df["train_mse"], df["test_mse"] = loss / 2, loss / 2
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("network, study, title, ylabel", [
    ("emulator", "ehr", "emulator (ehr)", "MSE (standardized outputs)"),
    ("flow_delta0.50", "structural", "flow (structural, delta=0.5)", "negative log-likelihood (nats)"),
    ("encoder_decoder_delta1", "ehr", "encoder_decoder (ehr, delta=1)", "weighted total loss"),
    ("npe_delta2", "", "NPE (delta=2)", "negative log-likelihood (nats)"),
])
def test_training_loss_figure_is_named_by_the_network(network, study, title, ylabel, tmp_path):
    out = lp.plot_training_losses(str(_emulator_csv(tmp_path / "l.csv", False)), str(tmp_path / "l.png"),
                                  network=network, study=study)
    assert (out["title"], out["ylabel"], out["cut"]) == (title, ylabel, {})
    assert (tmp_path / "l.png").stat().st_size > 10_000


def test_weighted_emulator_gets_its_own_label_and_bad_names_are_refused(tmp_path):
    """The label of a weighted emulator loss names the weighting its model file records."""
    import torch

    csv = str(_emulator_csv(tmp_path / "l.csv", True))
    assert lp.plot_training_losses(csv, str(tmp_path / "l.png"), "emulator")["ylabel"] == "weighted MSE (standardized outputs)"
    for hyper, label in [({"variance_floor": 0.01, "relative_weight": 0.0}, "MSE, output variances floored"),
                         ({"variance_floor": None, "relative_weight": 0.5}, "MSE, rows weighted by 1/|y|² (a = 0.5)"),
                         ({"variance_floor": 0.01, "relative_weight": 1},
                          "MSE, output variances floored, rows weighted by 1/|y|² (a = 1)")]:
        torch.save({"format": networks.FORMAT, "info": {"stage": "emulator", "hyper": hyper}}, tmp_path / "m.pt")
        assert lp.plot_training_losses(csv, str(tmp_path / "l.png"), "emulator", model=str(tmp_path / "m.pt"))["ylabel"] == label
    with pytest.raises(ValueError, match="'emulator_delta0.5'"):
        lp.plot_training_losses(csv, str(tmp_path / "x.png"), "emulator_delta0.5")
    assert not (tmp_path / "x.png").exists()


def test_restart_candidates_are_marked_and_kept_in_view(tmp_path, monkeypatch):
    """A network trained with restarts: its model file's restart record is read back, every
    finite candidate score lies inside the y limits (the rejected ones may sit far above the
    kept curve), and a diverged candidate is left out of the limits."""
    import torch
    from matplotlib.figure import Figure

    csv = str(_emulator_csv(tmp_path / "l.csv", False))  # losses fall from 1.1 to ~0.007
    record = {"epochs": 50, "chosen": 1, "seeds": [7, 8, 9, 10], "test_loss": [30.0, 0.09, 5.0, float("inf")]}
    fmt = networks.FORMAT
    torch.save({"format": fmt, "info": {"stage": "encoder_decoder", "restart": record}}, tmp_path / "m.pt")
    assert lp.restart_record(tmp_path / "m.pt") == record
    torch.save({"format": fmt, "info": {}}, tmp_path / "plain.pt")
    assert lp.restart_record(tmp_path / "plain.pt") is None
    torch.save({"format": "x", "info": {"restart": record}}, tmp_path / "bad.pt")  # not a model file
    with pytest.raises(ValueError, match=re.escape(f"bad.pt: not a {fmt} model file (format='x')")):
        lp.restart_record(tmp_path / "bad.pt")

    captured = {}
    savefig = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (captured.setdefault("fig", fig), savefig(fig, *a, **k)))
    out = lp.plot_training_losses(csv, str(tmp_path / "r.png"), "encoder_decoder_delta0", "structural",
                                  model=str(tmp_path / "m.pt"))
    monkeypatch.undo()
    assert out["restart"] == record and out["cut"] == {}
    ax = captured["fig"].axes[0]
    lo, hi = ax.get_ylim()
    assert lo < 0.007 and 30.0 < hi < 60.0  # the worst finite candidate is in view, inf is not
    marks = {line.get_label(): np.asarray(line.get_ydata(), float) for line in ax.get_lines()}
    kept = [v for k, v in marks.items() if k.startswith("kept")]
    others = [v for k, v in marks.items() if k.startswith("other")]
    assert len(kept) == 1 and kept[0].tolist() == [0.09]
    assert len(others) == 1 and sorted(others[0].tolist()) == [5.0, 30.0]
    assert any("1 diverged" in k for k in marks)
    plain = lp.plot_training_losses(csv, str(tmp_path / "p.png"), "emulator", model=str(tmp_path / "plain.pt"))
    assert plain["restart"] is None
    # screened to a reconstruction target: the legend says the kept one is the best of those that met it
    screened = record | {"chosen": 2, "target": 0.05, "worst_reconstruction": [0.01, 0.3, 0.02, None]}
    torch.save({"format": fmt, "info": {"stage": "encoder_decoder", "restart": screened}}, tmp_path / "s.pt")
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (captured.__setitem__("fig", fig), savefig(fig, *a, **k)))
    lp.plot_training_losses(csv, str(tmp_path / "s.png"), "encoder_decoder_delta0", "structural",
                            model=str(tmp_path / "s.pt"))
    labels = [line.get_label() for line in captured["fig"].axes[0].get_lines()]
    assert "kept: best test loss at epoch 50 of the 2 of 4\nwith every parameter reconstructed (MSE <= 0.05)" in labels


def test_figure_modules_choose_no_backend_and_draw_with_a_display_set(tmp_path):
    """Importing the figure modules and drawing a loss figure neither imports pyplot nor picks a
    backend, so a figure is written the same with or without a display (here an unreachable one)."""
    import os
    import subprocess
    import sys

    from matplotlib.image import imread

    csv = _emulator_csv(tmp_path / "l.csv", False)
    code = (
        "import sys, matplotlib\n"
        "from cvsim6.reporting import figures, loss_figures, stiffness_figures, ehr_figures, calibration_figures, "
        "data_figures\n"
        f"cut = loss_figures.plot_losses({str(csv)!r}, {str(tmp_path / 'l.png')!r})\n"
        "print(cut, matplotlib.rcParams._get_backend_or_none(), 'matplotlib.pyplot' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MPLBACKEND", "DISPLAY")}
    for display in (None, ":99"):
        run_env = env if display is None else {**env, "DISPLAY": display}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=run_env, check=True)
        assert out.stdout.split() == ["{}", "None", "False"], out.stderr
        assert imread(tmp_path / "l.png").shape == (675, 1050, 4)  # 7 x 4.5 inches at 150 dpi
