"""Error statistics count the rows they leave out; the data behind the evaluation figures (the
emulator's relative l2 errors, NN_f samples) and the figures drawn from them."""
import json
import logging

import numpy as np
import pandas as pd
import pytest

from cvsim6 import nets as networks
from cvsim6 import paper_values, registry
from cvsim6.data import datasets
from cvsim6.reporting import evaluation_figures
from cvsim6.studies import evaluation


def test_error_statistics_count_left_out_rows(caplog):
    y = np.zeros((5, 16))
    yhat = np.zeros((5, 16))
    yhat[:, 0] = [1.0, -1.0, 3.0, -3.0, 2.0]
    yhat[2, 5] = np.nan  # left out everywhere: |err| 1, 1, 3, 2 remain
    yhat[4, 9] = np.inf
    with caplog.at_level(logging.WARNING, logger="cvsim6.studies.evaluation"):
        s = evaluation.error_statistics(y, yhat)
    assert s.loc["Hr"].tolist() == pytest.approx([5 / 3, 3.0, np.std([1, 1, 3])])
    assert s.attrs == {"n_rows": 5, "n_used": 3, "n_nonfinite": 2}
    assert "2 of 5 rows left out" in caplog.text
    assert evaluation.nonfinite_words(s) == "; 2 rows with a non-finite value left out"
    assert evaluation.nonfinite_words(evaluation.error_statistics(y, y)) == ""
    none_left = evaluation.error_statistics(y[:1], np.full((1, 16), np.nan))
    assert none_left.attrs["n_used"] == 0 and none_left.isna().all().all()


def test_emulator_validation_caption_counts_left_out_rows(tmp_path, monkeypatch):
    class Emulator:
        def predict(self, v):
            out = np.zeros((len(v), 16))
            out[0, 3] = np.nan
            return out

    monkeypatch.setattr(evaluation, "load_model", lambda path: Emulator())
    monkeypatch.setattr(evaluation.datasets, "load_split", lambda path: (np.zeros((4, 23)), np.ones((4, 16))))
    evaluation.emulator_validation("m.pt", "v.parquet", str(tmp_path / "t.csv"), str(tmp_path / "t.md"), "ehr")
    md = (tmp_path / "t.md").read_text()
    assert "on the 4 validation sets (ehr study; 1 row with a non-finite value left out)" in md
    assert (pd.read_csv(tmp_path / "t.csv")["Mean (ours)"] == 1.0).all()


@pytest.fixture
def drawn(monkeypatch):
    """The figures the evaluation figure functions would save, in order."""
    figures = []
    monkeypatch.setattr(evaluation_figures, "save_figure", lambda fig, path: figures.append(fig))
    return figures


def test_emulator_l2_errors_and_their_histogram(tmp_path, monkeypatch, drawn):
    """Outputs y = 1 everywhere (norm 4); the emulator answers y + 0.4 e_0 in row 0, y + 0.8 e_1
    in row 1 and y elsewhere: errors 0.1, 0.2, 0, 0, in row order; the summary's max, mean and the
    paper's EHR max; the histogram counts every set and its title gives the same numbers."""
    class Emulator:
        def predict(self, v):
            out = np.ones((len(v), 16))
            out[0, 0] += 0.4
            out[1, 1] += 0.8
            return out

    monkeypatch.setattr(evaluation, "load_model", lambda path: Emulator())
    monkeypatch.setattr(evaluation.datasets, "load_split", lambda path: (np.zeros((4, 23)), np.ones((4, 16))))
    errors, summary = tmp_path / "l2.csv", tmp_path / "l2.json"
    evaluation.emulator_l2_errors("m.pt", "v.parquet", str(errors), str(summary), study="ehr")
    np.testing.assert_allclose(pd.read_csv(errors)["rel_l2_error"], [0.1, 0.2, 0.0, 0.0], atol=1e-15)
    info = json.loads(summary.read_text())
    assert info == {"study": "ehr", "n": 4, "max": pytest.approx(0.2), "mean": pytest.approx(0.075),
                    "paper_max": paper_values.EHR_EMULATOR_MAX_REL_L2}

    evaluation_figures.emulator_l2_histogram(str(errors), str(summary), "unused.png")
    ax = drawn.pop().axes[0]
    assert sum(patch.get_height() for patch in ax.patches) == 4
    assert ax.get_title().startswith("ehr emulator, 4 validation sets: max 20.000% (paper: ")
    assert ax.get_title().endswith("mean 7.500%")


def test_flow_samples_and_their_marginals(tmp_path, drawn):
    """The samples written are NN_f's draws for the seed, in physical units (drawn again here
    with the same generator); the figure puts the data and the samples of each output over
    the same bins, labelled with units."""
    import torch

    flow = networks.RealNVP(hidden=8, blocks=2, layers_per_block=2)
    networks.save_model(flow, tmp_path / "flow.pt")
    samples = tmp_path / "flow_samples.parquet"
    evaluation.flow_samples(str(tmp_path / "flow.pt"), str(samples), n_samples=300, seed=5)
    drawn_samples = datasets.read_dataset(samples)
    assert list(drawn_samples.columns) == list(registry.OUTPUT_NAMES)
    again = networks.load_model(tmp_path / "flow.pt").sample_physical(300, generator=torch.Generator().manual_seed(5))
    np.testing.assert_array_equal(drawn_samples.to_numpy(), again)
    assert datasets.dataset_units(samples)["P_a_sys"] == "mmHg"

    y = np.random.default_rng(0).normal(size=(200, 16))
    validation = tmp_path / "validation.parquet"
    datasets.write_dataset(pd.DataFrame(y, columns=list(registry.OUTPUT_NAMES)), validation)
    evaluation_figures.flow_marginals(str(samples), str(validation), "unused.png")
    fig = drawn.pop()
    assert len(fig.axes) == 16
    assert [ax.get_xlabel() for ax in fig.axes] == [evaluation_figures.label(n) for n in registry.OUTPUT_NAMES]
    assert fig.axes[1].get_xlabel() == "P_a_sys (mmHg)"
    data_bars = [p for p in fig.axes[0].patches if p.get_fill()]
    lo, hi = np.percentile(y[:, 0], [0.1, 99.9])
    pad = 0.1 * (hi - lo)
    assert len(data_bars) == 49 and data_bars[0].get_x() == pytest.approx(lo - pad)
    assert fig._suptitle.get_text() == "Output marginals: 200 validation outputs (blue) vs 300 NN_f samples (red)"
