"""Error statistics count the rows they leave out."""
import logging

import numpy as np
import pandas as pd
import pytest

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
