"""The spread over seeds (target ``seeds``): its arithmetic on headline files of known ratios."""
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cvsim6 import paper_values
from cvsim6.reporting import scorecard, seed_scorecard
from test_scorecard import _known_ratio_files, _paper_files

SEEDS = [7, 8, 9]


def _seed_files(tmp_path) -> dict:
    """Named inputs of three seeds: 7 at the paper's numbers, 8 at the known ratios of
    test_scorecard, 9 at the paper's but the manifold error 0.8 x the paper's."""
    files = {}
    for seed in SEEDS:
        (tmp_path / str(seed)).mkdir()
        make = _known_ratio_files if seed == 8 else _paper_files
        mine = make(tmp_path / str(seed))
        if seed == 9:
            h = paper_values.STRUCTURAL_HEADLINES
            mine["manifold"].write_text(json.dumps({"max_rel_l2_error": 0.8 * h["max_rel_error_manifold"]}))
        files.update({f"seed{seed}_{k}": str(v) for k, v in mine.items()})
    return files


def _outputs(tmp_path) -> dict:
    """The step's four output paths, in its argument order."""
    return {n: str(tmp_path / f) for n, f in (("csv", "seeds.csv"), ("md", "seeds.md"),
                                               ("best_delta_csv", "best.csv"), ("best_delta_md", "best.md"))}


def _as_inputs(published: dict) -> dict:
    """The published networks' headline files as the step's named inputs."""
    return {f"published_{k}": v for k, v in published.items()}


def _row(table: pd.DataFrame, phrase: str) -> pd.Series:
    rows = table[table["Headline"].str.contains(phrase, regex=False)]
    assert len(rows) == 1, phrase
    return rows.iloc[0]


def test_spread_of_known_ratios_over_three_seeds(tmp_path):
    files = _seed_files(tmp_path)
    (tmp_path / "pub").mkdir()
    published = {k: str(v) for k, v in _paper_files(tmp_path / "pub").items()}
    out = _outputs(tmp_path)
    seed_scorecard.write_seed_scorecard(*out.values(), SEEDS, 7, **files, **_as_inputs(published))
    table = pd.read_csv(out["csv"])
    # the 22 headlines but the 8 stiffness rows, which do not depend on the networks
    assert len(table) == 14 and not table["Headline"].str.startswith("Stiffness").any()
    expected = {  # phrase -> ratios of seeds 7, 8, 9 (seed 8's from test_scorecard's known-ratio files)
        "Structural emulator, mean": (1.0, 3.0, 1.0),
        "Amortized inversion, mean": (1.0, 0.5, 1.0),
        "Manifold reconstruction of y*": (1.0, 0.5, 0.8),
        "Missing data": (1.0, 3.0, 1.0),
        "EHR: outputs whose lowest e_k is at the paper's delta": (1.0, 12 / 13, 1.0),
    }
    for phrase, ratios in expected.items():
        row = _row(table, phrase)
        assert row["min / paper"] == pytest.approx(min(ratios), rel=1e-9), phrase
        assert row["median / paper"] == pytest.approx(np.median(ratios), rel=1e-9), phrase
        assert row["max / paper"] == pytest.approx(max(ratios), rel=1e-9), phrase
        assert row["published / paper"] == pytest.approx(1.0, rel=1e-9), phrase
    # values per seed are the headline values of each seed's own files
    manifold = _row(table, "Manifold reconstruction of y*")
    paper_pct = 100 * paper_values.STRUCTURAL_HEADLINES["max_rel_error_manifold"]
    assert [manifold[f"seed {s}"] for s in SEEDS] == pytest.approx([paper_pct, 0.5 * paper_pct, 0.8 * paper_pct])
    assert manifold["median"] == pytest.approx(0.8 * paper_pct)
    # the best noise level per output: seed 8 leaves the paper's only for P_r_edp (0.5 against 0.25)
    best = pd.read_csv(out["best_delta_csv"]).set_index("Output")
    assert len(best) == 13
    differs = best.index[best["seed 8"] != best["paper"]]
    assert list(differs) == ["P_r_edp"] and best.loc["P_r_edp", ["paper", "seed 8"]].tolist() == [0.25, 0.5]
    assert (best["seed 7"] == best["paper"]).all() and (best["published"] == best["paper"]).all()
    assert "seed 7: 13 of 13, seed 8: 12 of 13, seed 9: 13 of 13, published: 13 of 13" in Path(
        out["best_delta_md"]).read_text()
    md = Path(out["md"]).read_text()
    assert "results are absent" not in md
    # within 1.5x: the min is seed 8's ratio where below 1, out for its two 0.5s (inversion mean,
    # manifold); the max is seed 8's where above 1, out for its three 3s (emulator mean, missing
    # data, e_k at delta = 2); the median is 1 (or 0.95, 0.9, 0.8) everywhere
    assert "**min** over the seeds: 12 of 14 within 1.5x" in md
    assert "**median** over the seeds: 14 of 14 within 1.5x" in md
    assert "**max** over the seeds: 11 of 14 within 1.5x" in md


def test_reproduction_scorecard_shows_the_spread_beside_the_default_seed(tmp_path):
    files = _seed_files(tmp_path)
    out = _outputs(tmp_path)
    seed_scorecard.write_seed_scorecard(*out.values(), SEEDS, 7, **files)
    assert "published" not in pd.read_csv(out["csv"]).columns  # its files are not given
    assert "results are absent, so every bar is the paper's value" in Path(out["md"]).read_text()
    default = {k: files[f"seed7_{k}"] for k in scorecard.HEADLINE_FILES}
    text = (tmp_path / "seeds.csv").read_text()
    scorecard.write_scorecard(str(tmp_path / "card.csv"), str(tmp_path / "card.md"), "trained", {},
                              seed_spread=text, **default)
    card = pd.read_csv(tmp_path / "card.csv")
    manifold = _row(card, "Manifold reconstruction of y*")
    assert manifold["trained / paper"] == pytest.approx(1.0)
    assert [manifold[f"trained {s} over seeds / paper"] for s in ("min", "median", "max")] == pytest.approx(
        [0.5, 0.8, 1.0])
    # the stiffness rows have no spread
    assert card.loc[card["Headline"].str.startswith("Stiffness"), "trained max over seeds / paper"].isna().all()
    assert "**trained over seeds** 7, 8, 9" in (tmp_path / "card.md").read_text()
    # without the text, no spread columns
    scorecard.write_scorecard(str(tmp_path / "c2.csv"), str(tmp_path / "c2.md"), "trained", {}, **default)
    assert not any("over seeds" in c for c in pd.read_csv(tmp_path / "c2.csv").columns)


def test_a_seed_without_its_files_is_named(tmp_path):
    files = _seed_files(tmp_path)
    del files["seed8_manifold"]
    with pytest.raises(ValueError, match=r"seed 8: headline files missing: \['manifold'\]"):
        seed_scorecard.files_by_seed(SEEDS, files)


def test_goal_bar_is_the_paper_or_the_published_networks_score(tmp_path):
    """The bar is the paper's value, or the published networks' where they score above it; a
    headline meets it when every seed does. Seed 8's known ratios put it above the paper on the
    emulator mean (3x), max (1.3x), modes (15 of 12), missing data (3x), EHR emulator (1.3x) and e_k
    at delta = 0.25, 1 and 2 (1.1x, 1.3x, 3x); the published networks here score 1.4x on the EHR
    emulator."""
    files = _seed_files(tmp_path)
    (tmp_path / "pub").mkdir()
    published = {k: str(v) for k, v in _paper_files(tmp_path / "pub").items()}
    Path(published["ehr_emulator"]).write_text(json.dumps({"max": 1.4 * paper_values.EHR_EMULATOR_MAX_REL_L2}))
    out = _outputs(tmp_path)
    seed_scorecard.write_seed_scorecard(*out.values(), SEEDS, 7, **files, **_as_inputs(published))
    table = pd.read_csv(out["csv"]).set_index("key")
    assert table.loc["ehr_emulator_l2", "bar / paper"] == pytest.approx(1.4)
    assert table.loc["manifold_l2", "bar / paper"] == 1.0
    met = table["every seed meets the bar"]
    assert met["ehr_emulator_l2"] and met["manifold_l2"] and met["structural_inversion_max"]
    assert not met[["structural_emulator_mean", "structural_emulator_max", "svd_modes", "missing_l2",
                    "ek_0.25", "ek_1", "ek_2"]].any()
    # 12 of 13 at the paper's best noise level (seed 8) meets the goal of 10
    assert table.loc["ek_best_delta", "bar / paper"] == pytest.approx(10 / 13) and met["ek_best_delta"]
    assert pd.isna(met["svd_energy"])  # not a goal headline
    # 13 goal headlines: the 12 lower-is-better and the best noise level; 7 missed
    assert "6 of 13 headlines met." in Path(out["md"]).read_text()
