"""The reproduction scorecard's arithmetic on tables with known answers."""
import numpy as np
import pandas as pd
import pytest

from cvsim6 import paper_values
from cvsim6.reporting import scorecard
from cvsim6.registry import OUTPUT_NAMES


def ehr_table(factor: float, counts: list[int]) -> pd.DataFrame:
    """Table 5 in our layout with every e_k = factor x the paper's."""
    t = pd.DataFrame({"Output": list(OUTPUT_NAMES)})
    for i, d in enumerate(paper_values.EHR_DELTAS):
        t[f"delta={d:g}"] = [factor * v[i] if v[i] is not None else np.nan
                             for v in (paper_values.EHR_EK[n] for n in OUTPUT_NAMES)]
    t["Counts"] = [f"{c}/46" for c in counts]
    return t


COUNTS = [46, 46, 46, 44, 11, 46, 46, 44, 46, 3, 0, 3, 45, 46, 46, 46]  # the real patients'


def test_outputs_counted_are_those_seen_in_more_than_10_patients():
    assert scorecard.ek_outputs(ehr_table(1.0, COUNTS)) == [
        "Hr", "P_a_sys", "P_a_dia", "P_r_sys", "P_r_dia", "P_pa_sys", "P_pa_dia", "P_r_edp", "P_w",
        "LVEF", "CO", "SVR", "PVR"]


def test_geometric_mean_ratio_and_best_delta():
    assert scorecard.geomean_ratio([2.0, 8.0], [1.0, 1.0]) == pytest.approx(4.0)
    assert scorecard.geomean_ratio([1.0, np.nan], [2.0, 1.0]) == pytest.approx(0.5)  # NaN rows skipped
    t = ehr_table(1.3, COUNTS)
    outputs = scorecard.ek_outputs(t)
    assert scorecard.best_delta_agreement(t, outputs) == 13  # same ordering as the paper
    t.loc[t["Output"] == "Hr", "delta=2"] = 0.0  # Hr now best at delta = 2, the paper's at 0.5
    assert scorecard.best_delta_agreement(t, outputs) == 12


def _paper_files(tmp_path) -> dict:
    """Headline files of a source whose every number is the paper's."""
    h = paper_values.STRUCTURAL_HEADLINES
    paper_table = pd.DataFrame({"Output": list(OUTPUT_NAMES)})
    for stat in ("mean", "max"):
        paper_table[f"{stat.capitalize()} (ours)"] = paper_values.EMULATOR_VALIDATION_STRUCTURAL[stat]
        paper_table[f"{stat.capitalize()} (paper)"] = paper_values.EMULATOR_VALIDATION_STRUCTURAL[stat]
    rows = []
    for instant, ref in paper_values.STIFFNESS_EXTREMES.items():
        rows += [(instant, f"lambda_{j + 1} (1/s)", lam, lam) for j, lam in enumerate(ref["lambdas"])]
    files = {"stiffness": tmp_path / "st.csv", "structural_emulator": tmp_path / "e.csv",
             "structural_inversion": tmp_path / "i.csv", "manifold": tmp_path / "m.json",
             "svd": tmp_path / "s.json", "missing": tmp_path / "x.json", "ehr_emulator": tmp_path / "l2.json",
             "ehr_errors": tmp_path / "ek.csv"}
    pd.DataFrame(rows, columns=["Instant", "Quantity", "This work", "Paper"]).to_csv(files["stiffness"], index=False)
    paper_table.to_csv(files["structural_emulator"], index=False)
    paper_table.to_csv(files["structural_inversion"], index=False)
    files["manifold"].write_text(f'{{"max_rel_l2_error": {h["max_rel_error_manifold"]}}}')
    files["svd"].write_text(f'{{"modes": {h["modes_99"]}, "energy": {h["energy_at_modes"]}}}')
    files["missing"].write_text(f'{{"max_rel_l2_error_observed": {h["max_rel_error_missing"]}}}')
    files["ehr_emulator"].write_text(f'{{"max": {paper_values.EHR_EMULATOR_MAX_REL_L2}}}')
    ehr_table(1.0, COUNTS).to_csv(files["ehr_errors"], index=False)
    return files


def test_scorecard_of_a_source_equal_to_the_paper(tmp_path):
    """A source whose every number is the paper's gets ratio 1 on every headline."""
    files = _paper_files(tmp_path)
    missing_other = {k: str(tmp_path / "absent" / p.name) for k, p in files.items()}
    scorecard.write_scorecard(str(tmp_path / "card.csv"), str(tmp_path / "card.md"), "trained",
                              {"published": missing_other}, **{k: str(v) for k, v in files.items()})
    card = pd.read_csv(tmp_path / "card.csv")
    assert len(card) == 22
    np.testing.assert_allclose(card["trained / paper"], 1.0, rtol=1e-12)
    md = (tmp_path / "card.md").read_text()
    assert "22 of 22 within 1.15x" in md and "not built yet, so not shown: published" in md


def test_resampled_manifold_headline_is_a_row_of_its_own(tmp_path):
    """With the reconstruction's spread in its summary, the median of the resampled max is one
    more row, its ratio against the paper's max; the first-100 headline stays as it was."""
    h = paper_values.STRUCTURAL_HEADLINES
    files = _paper_files(tmp_path)
    files["manifold"].write_text(
        f'{{"max_rel_l2_error": {h["max_rel_error_manifold"]}, "max_rel_l2_error_resampled": {{"n_simulated": 5000, '
        f'"subset": 100, "resamples": 2000, "q10": 0.001, "q50": {2 * h["max_rel_error_manifold"]}, "q90": 0.01}}}}')
    values, rows = scorecard.headline_values({k: str(v) for k, v in files.items()})
    assert values["manifold_l2"] == pytest.approx(100 * h["max_rel_error_manifold"])
    assert values["manifold_l2_resampled"] == pytest.approx(200 * h["max_rel_error_manifold"])
    row = next(r for r in rows if r.key == "manifold_l2_resampled")
    assert "2,000 random sets of 100 of 5,000 draws" in row.label
    assert scorecard._ratio(values[row.key], row) == pytest.approx(2.0)
    assert len(rows) == 23
