"""The EHR error criterion e_k, inversion of bad or out-of-distribution input, unit checks.
The EHR stage end to end is checked in test_workflow_smoke.py."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cvsim6.studies import ehr as ehr_study
from cvsim6 import registry

from conftest import LOCAL_EHR_CSV as REAL, needs_local_ehr, toy_ehr_networks  # REAL: the local copy of the EHR data


def test_error_per_output_is_the_papers_criterion():
    names = registry.OUTPUT_NAMES
    obs = pd.DataFrame(np.nan, index=pd.Index([1, 2], name="patient"), columns=list(names))
    obs.loc[1, "Hr"], obs.loc[2, "Hr"] = 60.0, 80.0
    obs.loc[2, "CO"] = 5.0
    pred = pd.DataFrame({"id": [1, 1, 2, 2], "draw": [0, 1, 0, 1]})
    for n in names:
        pred[ehr_study.PRED + n] = 0.0
    pred[ehr_study.PRED + "Hr"] = [61.0, 63.0, 80.0, 79.0]  # |err| means: 2.0 and 0.5
    pred[ehr_study.PRED + "CO"] = [9.0, 9.0, 4.0, 6.0]  # only patient 2 observed: 1.0
    e = ehr_study.error_per_output(obs, pred)
    assert e.loc["Hr", "e_k"] == pytest.approx(1.25) and e.loc["Hr", "count"] == 2
    assert e.loc["CO", "e_k"] == pytest.approx(1.0) and e.loc["CO", "count"] == 1
    assert np.isnan(e.loc["V_l_sys", "e_k"]) and e.loc["V_l_sys", "count"] == 0


# ----------------------------------------------------------------------------- bad input, OOD
@pytest.fixture(scope="module")
def gaussian_twin():
    """Small networks on 440 simulated EHR-prior sets (conftest.toy_ehr_networks); the flow's
    couplings are the identity, so its density is the Gaussian of the standardized outputs
    (fitted on the first 400). Returns ``(flow, encoder_decoder, emulator, outputs (440, 16))``."""
    flow, ed, emu, _, y = toy_ehr_networks(440, 6, flow_rows=400)
    return flow, ed, emu, y


def test_obvious_outlier_ranks_below_typical_simulated_patients(gaussian_twin):
    flow, ed, emu, y = gaussian_twin
    names = list(registry.OUTPUT_NAMES)
    obs = pd.DataFrame(y[400:440], columns=names)  # 40 simulated patients the reference does not hold
    obs.iloc[:, [2, 4, 6, 8, 10, 14, 15]] = np.nan  # the paper's missing set
    outlier = obs.iloc[0].copy()
    outlier[["Hr", "P_r_sys", "LVEF"]] = [25.0, 380.0, 0.03]  # possible in their units, far from any simulation
    obs.loc["outlier"] = outlier
    warnings = []
    df = ehr_study.invert_observations(obs, flow, ed, emu, n_latent=2, n_flow_samples=4096, reference_outputs=y[:400],
                                       n_reference=200, reference_flow_samples=1024,
                                       on_warning=lambda pid, msg: warnings.append((pid, msg)))
    per = df.groupby("id", sort=False).first()
    assert (per["ood_reference_size"] == 200).all()  # resolution 0.5 percentage points
    typical = per.drop(index="outlier")["ood_percentile"]
    assert per.loc["outlier", "ood_percentile"] == 0.0  # less likely than all 200 simulated references
    assert (typical > 0).all() and 25 < typical.median() < 75  # exchangeable with the references
    assert per.loc["outlier", "outside_training"] == "Hr;P_r_sys;LVEF"
    assert (per.drop(index="outlier")["outside_training"] == "").all()
    assert [p for p, _ in warnings] == ["outlier"] * 3
    assert warnings[0][1].startswith("Hr = 25 bpm is far outside the training range [")


def test_invert_observations_reports_instead_of_aborting(gaussian_twin):
    flow, ed, emu, y = gaussian_twin
    obs = pd.DataFrame(y[400:403], columns=list(registry.OUTPUT_NAMES), index=["a", "b", "c"])
    obs.loc["b"] = np.nan
    seen = []
    df = ehr_study.invert_observations(obs, flow, ed, emu, n_latent=3, n_flow_samples=4096, reference_outputs=y[:400],
                                       n_reference=20, reference_flow_samples=256,
                                       on_warning=lambda pid, msg: seen.append((pid, msg)))
    assert list(df["id"]) == ["a"] * 3 + ["b"] + ["c"] * 3
    assert list(df.groupby("id", sort=False)["status"].first()) == ["ok", "not inverted: no output given", "ok"]
    assert seen == [("b", "not inverted: no output given")]
    assert df.loc[df["id"] == "b", list(registry.PARAMETER_NAMES)].isna().all().all()
    # the blank row and the rows after a patient do not change its inversion (seeds follow the row's position)
    alone = ehr_study.invert_observations(obs.loc[["a"]], flow, ed, emu, n_latent=3, n_flow_samples=4096,
                                          reference_outputs=y[:400], n_reference=20, reference_flow_samples=256)
    pd.testing.assert_frame_equal(alone, df[df["id"] == "a"].reset_index(drop=True))


def test_invert_observations_rejects_before_computing(gaussian_twin):
    flow, ed, emu, y = gaussian_twin
    kw = dict(n_latent=2, n_flow_samples=100, reference_outputs=y[:400], n_reference=5)
    with pytest.raises(ValueError, match=r"no observations to invert \(the table has no rows\)"):
        ehr_study.invert_observations(pd.DataFrame(columns=["Hr", "CO"]), flow, ed, emu, **kw)
    pct = pd.DataFrame({"Hr": [70.0, 80.0], "LVEF": [0.6, 55.0]}, index=["p1", "p2"])
    with pytest.raises(ValueError, match=r"^LVEF is a fraction \(0-1\); got 55 in observation 'p2': percent\?$"):
        ehr_study.invert_observations(pct, flow, ed, emu, **kw)
    text = pd.DataFrame({"Hr": [70.0, "fast"]}, index=["p1", "p2"])
    with pytest.raises(ValueError, match=r"observation 'p2': Hr = 'fast' is not a number"):
        ehr_study.invert_observations(text, flow, ed, emu, **kw)


def test_unit_problems():
    assert ehr_study.unit_problem("LVEF", 0.55) is None and ehr_study.unit_problem("LVEF", np.nan) is None
    assert ehr_study.unit_problem("LVEF", 55.0) == ("LVEF is a fraction (0-1)", "percent?")
    assert ehr_study.unit_problem("LVEF", -0.1) == ("LVEF is a fraction (0-1)", "")
    assert ehr_study.unit_problem("CO", 5000.0) == ("CO is in L/min (0.1 to 50)", "mL/min?")
    assert ehr_study.unit_problem("P_a_sys", 16000.0)[1] == "Pa? (1 mmHg = 133.3 Pa)"
    assert ehr_study.unit_problem("PVR", 2.5) is None  # Wood or a tiny gradient: not decidable by value
    obs = pd.DataFrame({"LVEF": [0.5, 55.0, 60.0], "CO": [5.0, 4.0, 0.0]})
    assert [p[:3] for p in ehr_study.unit_problems(obs)] == [(1, "LVEF", 55.0), (2, "LVEF", 60.0), (2, "CO", 0.0)]


@needs_local_ehr
def test_real_patients_pass_the_unit_checks():
    from cvsim6.data import ehr

    assert ehr_study.unit_problems(ehr.ehr_outputs(REAL)) == []  # all 84, selected or not


def test_not_inverted_patients_leave_e_k_and_ood_table_readable(tmp_path):
    names = registry.OUTPUT_NAMES
    obs = pd.DataFrame(np.nan, index=pd.Index([1, 2], name="patient"), columns=list(names))
    obs["Hr"] = [60.0, 80.0]
    pred = pd.DataFrame({"id": [1, 1, 2], "status": ["ok", "ok", "not inverted: no output given"],
                         "draw": [0, 1, None]})
    for n in names:
        pred[ehr_study.PRED + n] = [0.0, 0.0, np.nan]
    pred[ehr_study.PRED + "Hr"] = [61.0, 63.0, np.nan]
    e = ehr_study.error_per_output(obs, pred)
    assert e.loc["Hr", "e_k"] == pytest.approx(2.0)  # patient 2 has no predictions
    pred["log_density"] = [-3.0, -3.0, np.nan]
    pred["ood_percentile"] = [0.5, 0.5, np.nan]
    pred["ood_reference_size"] = [200, 200, None]
    pred["outside_training"] = ["", "", ""]
    pred.to_parquet(tmp_path / "p.parquet")
    ehr_study.ood_table(str(tmp_path / "p.parquet"), str(tmp_path / "t.csv"), str(tmp_path / "t.md"))
    t = pd.read_csv(tmp_path / "t.csv")
    assert list(t["status"]) == ["ok", "not inverted: no output given"]
    assert list(t["flag (< 1st percentile)"]) == [True, False]
    assert "among 200 simulated outputs (resolution 0.5 percentage points)" in (tmp_path / "t.md").read_text()


def test_reference_without_simulated_outputs_is_the_seeded_flow_sample(gaussian_twin):
    """With no simulated outputs the training range comes from REFERENCE_FLOW_DRAWS flow samples
    drawn with the public seeded generator (stream [seed, 1]); the OOD rows are picked with seed."""
    from cvsim6.inference import inversion

    flow, _, _, _ = gaussian_twin
    ref = ehr_study._Reference.build(flow, None, n_reference=7, flow_samples=64, seed=5)
    gen = inversion.seeded_torch_generator(np.random.SeedSequence([5, 1]).generate_state(1)[0])
    drawn = flow.sample_physical(ehr_study.REFERENCE_FLOW_DRAWS, generator=gen)
    lo, hi = ehr_study.training_range(drawn)
    np.testing.assert_array_equal(ref.low, lo)
    np.testing.assert_array_equal(ref.high, hi)
    pick = np.random.default_rng(5).choice(len(drawn), size=7, replace=False)
    np.testing.assert_array_equal(ref.rows, drawn[pick])
    assert ref.outside(np.r_[hi[0] + 1.0, np.full(15, np.nan)]) == ["Hr"]


def test_patient_figure_draws_the_measurements_and_the_predictions(tmp_path, monkeypatch):
    """The EHR figure from a small patients CSV and predictions Parquet: one panel per measured
    output, the measurement as the star, each patient's draws as dots, +-3 sigma bars."""
    import subprocess
    import sys

    from cvsim6.reporting import ehr_figures

    assert ehr_figures.PRED == ehr_study.PRED
    names = list(registry.OUTPUT_NAMES)
    obs = pd.DataFrame(np.nan, index=pd.Index([4, 9], name="patient"), columns=names)
    obs["Hr"] = [62.0, 88.0]
    obs.loc[9, "CO"] = 4.5
    obs.to_csv(tmp_path / "patients.csv")
    pred = pd.DataFrame({"id": [4, 4, 4, 9, 9, 9], "noise_level": 0.5, "status": "ok", "draw": [0, 1, 2] * 2})
    for n in names:
        pred[ehr_study.PRED + n] = 1.0
    pred[ehr_study.PRED + "Hr"] = [60.0, 61.0, 65.0, 90.0, 86.0, 87.0]
    pred[ehr_study.PRED + "CO"] = [5.0, 5.1, 5.2, 4.0, 4.4, 4.9]
    pred.to_parquet(tmp_path / "p.parquet")
    assert list(ehr_figures.read_predictions(str(tmp_path / "p.parquet")).columns) == \
        ["id", "noise_level", *(ehr_study.PRED + n for n in names)]
    drawn = {}
    save = ehr_figures.save_figure
    monkeypatch.setattr(ehr_figures, "save_figure", lambda fig, p: (drawn.setdefault("fig", fig), save(fig, p)))
    ehr_figures.ehr_patient_figure(str(tmp_path / "patients.csv"), str(tmp_path / "p.parquet"),
                                   str(tmp_path / "patient_predictions_delta0.5.png"))
    fig = drawn["fig"]
    assert fig.get_suptitle().startswith("Patient-specific predictions, delta = 0.5")
    hr, co = [ax for ax in fig.axes if ax.get_visible()]
    assert (hr.get_ylabel(), co.get_ylabel()) == ("Hr (bpm)", "CO (L/min)")
    dots = [ln.get_ydata().tolist() for ln in hr.get_lines() if ln.get_marker() == "."][:2]
    assert dots == [[60.0, 61.0, 65.0], [90.0, 86.0, 87.0]]
    star = [ln for ln in co.get_lines() if ln.get_marker() == "*"][0]
    assert star.get_ydata().tolist() == [4.5] and [t.get_text() for t in co.get_xticklabels()] == ["9"]
    s_hr = registry.noise_std()[registry.OUTPUT_INDEX["Hr"]]
    np.testing.assert_allclose([p.get_height() for p in hr.patches], [6 * s_hr] * 2)
    np.testing.assert_allclose([p.get_y() for p in hr.patches], np.array([62.0, 88.0]) - 3 * s_hr)
    assert (tmp_path / "patient_predictions_delta0.5.pdf").is_file()
    out = subprocess.run([sys.executable, "-c", "import sys, cvsim6.reporting.ehr_figures; print(sorted(m for m in "
                          "sys.modules if m in ('torch', 'cvsim6.model.solver', 'cvsim6.data.datasets', "
                          "'matplotlib.pyplot') or m.startswith('cvsim6.studies') or m.startswith('cvsim6.nets')))"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stderr
