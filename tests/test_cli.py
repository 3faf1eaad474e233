"""The cvsim6 command line: simulate round trip, input errors, and ``invert`` against the library."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from conftest import gaussian_log_density, toy_ehr_networks
from cvsim6 import cli
from cvsim6 import nets as networks
from cvsim6 import registry
from cvsim6.data import datasets
from cvsim6.model import equations as model
from cvsim6.model import solver
from cvsim6.studies import ehr as ehr_study


def test_simulate_round_trip(tmp_path, structural_sets):
    P = structural_sets[:4]
    df = pd.DataFrame(P, columns=registry.PARAMETER_NAMES)
    df = df[list(reversed(df.columns))]  # any column order
    df["patient"] = ["a", "b", "c", "d"]  # other columns are carried over, first
    src = tmp_path / "params.csv"
    df.to_csv(src, index=False, float_format="%.17g")
    out = tmp_path / "sub" / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out)]) == 0
    got = pd.read_csv(out)
    assert list(got.columns) == ["patient"] + list(registry.OUTPUT_NAMES) + ["status"]
    assert list(got["patient"]) == ["a", "b", "c", "d"]
    expect, st = solver.simulate_batch(P)
    np.testing.assert_allclose(got[list(registry.OUTPUT_NAMES)].to_numpy(), expect, rtol=1e-9)
    assert (got["status"] == "ok").all()


def test_simulate_bad_input_names_parameter_and_row(tmp_path, default_params, capsys):
    P = np.repeat(default_params[None], 3, axis=0)
    P[2, registry.PARAMETER_INDEX["R_a"]] = 0.0
    src = tmp_path / "params.csv"
    pd.DataFrame(P, columns=registry.PARAMETER_NAMES).to_csv(src, index=False)
    out = tmp_path / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out)]) == 2
    # the third data row is line 4 of the file (header = line 1)
    assert capsys.readouterr().err.splitlines() == [f"error: {src}: line 4, column R_a: 0.0 mmHg·s/mL must be > 0"]
    assert not out.exists()


def _params_csv(default_params, edit=None) -> str:
    """Three default parameter sets as CSV text, ``edit(lines)`` applied to its lines."""
    text = pd.DataFrame([default_params] * 3, columns=registry.PARAMETER_NAMES).to_csv(index=False)
    lines = text.splitlines()
    if edit is not None:
        edit(lines)
    return "\n".join(lines) + "\n"


def _set(line: int, name: str, value: str):
    """Edit: cell ``name`` of file line ``line`` (1-based, header = 1) becomes ``value``."""
    def edit(lines):
        j = list(registry.PARAMETER_NAMES).index(name)
        cells = lines[line - 1].split(",")
        cells[j] = value
        lines[line - 1] = ",".join(cells)
    return edit


SIMULATE_BAD = {  # name: (file text or bytes from default_params, extra args, stderr line after "error: FILE")
    "text in a cell": (lambda d: _params_csv(d, _set(3, "C_a", "abc")), [], ": line 3, column C_a: 'abc' is not a number"),
    "blank cell": (lambda d: _params_csv(d, _set(2, "R_a", "")), [], ": line 2, column R_a: blank (a number is required)"),
    "NA cell": (lambda d: _params_csv(d, _set(4, "Hr", "NA")), [], ": line 4, column Hr: blank (a number is required)"),
    "infinite value": (lambda d: _params_csv(d, _set(3, "C_v", "inf")), [], ": line 3, column C_v: inf is not finite"),
    "negative compliance": (lambda d: _params_csv(d, _set(2, "C_pv", "-0.5")), [],
                            ": line 2, column C_pv: -0.5 mL/mmHg must be > 0"),
    "r_sys too large": (lambda d: _params_csv(d, _set(3, "r_sys", "0.7")), [], ": line 3, column r_sys: 0.7 must lie in (0, 2/3)"),
    # blank lines are skipped but counted: the bad cell is on line 6 of the file
    "blank lines before the bad row": (lambda d: _params_csv(d, lambda ls: (ls.insert(2, ""), ls.insert(3, ""),
                                                                           _set(6, "V0_l", "1O")(ls))),
                                       [], ": line 6, column V0_l: '1O' is not a number"),
    "header only": (lambda d: _params_csv(d).splitlines()[0] + "\n", [], ": no rows (the file has a header only)"),
    "empty file": (lambda d: "", [], ": the file is empty (no header, no rows)"),
    "not UTF-8 (a spreadsheet)": (lambda d: b"PK\x03\x04\x14\x00\x06\x00\x08\x00\xb0\x9c", [],
                                  ": not a CSV file (not UTF-8 text)"),
    "semicolons": (lambda d: _params_csv(d).replace(",", ";"), [],
                   ": line 1: the header is a single column: fields separated by ';'? cvsim6 reads comma-separated values"),
    "JSON": (lambda d: '{"Hr": 72}\n', [], ": line 1: no parameter column in the header; expected the 23 names "
             + ", ".join(registry.PARAMETER_NAMES)),
    "missing columns": (lambda d: _params_csv(d).replace("C_a,", "C_x,"), [], ": line 1: missing parameter column(s) C_a"),
    "repeated column": (lambda d: _params_csv(d).replace("C_v,", "C_a,", 1), [],
                        ": line 1: column C_a appears twice in the header"),
    "extra value in a row": (lambda d: _params_csv(d, lambda ls: ls.__setitem__(2, ls[2] + ",7")), [],
                             ": line 3: 24 values but the header (line 1) has 23 columns"),
}


@pytest.mark.parametrize("case", list(SIMULATE_BAD))
def test_simulate_bad_input_is_one_line_and_exit_2(case, tmp_path, default_params, capsys):
    make, extra, expected = SIMULATE_BAD[case]
    content = make(default_params)
    src = tmp_path / "params.csv"
    (src.write_bytes if isinstance(content, bytes) else src.write_text)(content)
    out = tmp_path / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out), *extra]) == 2
    assert capsys.readouterr().err.splitlines() == [f"error: {src}{expected}"]
    assert not out.exists()


def test_simulate_unreadable_files_and_options(tmp_path, default_params, capsys):
    good = tmp_path / "p.csv"
    good.write_text(_params_csv(default_params))
    out = str(tmp_path / "o.csv")
    cases = [
        ([str(tmp_path / "nope.csv"), "-o", out], f"error: {tmp_path / 'nope.csv'}: no such file"),
        ([str(tmp_path), "-o", out], f"error: {tmp_path}: is a directory, not a CSV file"),
        ([str(good), "-o", out, "--steps-per-cycle", "5"],
         f"error: --steps-per-cycle 5 is below the solver's minimum of {solver.MIN_STEPS_PER_CYCLE}"),
        ([str(good), "-o", str(good)], f"error: {good}: the output would overwrite the input"),
        ([str(good), "-o", str(tmp_path)], f"error: {tmp_path}: the output is a directory"),
    ]
    for argv, line in cases:
        assert cli.main(["simulate", *argv]) == 2
        assert capsys.readouterr().err.splitlines() == [line]
    assert not Path(out).exists()
    assert good.read_text() == _params_csv(default_params)  # the input was not overwritten


def test_simulate_flags_unphysical_rows_and_keeps_the_others(tmp_path, default_params, capsys):
    """A negative unstressed volume is simulated and flagged (status 8), not an error."""
    P = np.repeat(default_params[None], 3, axis=0)
    P[1, registry.PARAMETER_INDEX["V0_v"]] = -100.0
    src = tmp_path / "params.csv"
    pd.DataFrame(P, columns=registry.PARAMETER_NAMES).to_csv(src, index=False, float_format="%.17g")
    out = tmp_path / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.splitlines() == [f"simulated 3 parameter set(s) -> {out} (1 flagged, see the status column: line 3)"]
    got = pd.read_csv(out)
    assert list(got["status"]) == ["ok", solver.STATUS_REASONS[8], "ok"]
    expect, st = solver.simulate_batch(P)
    assert list(st) == [0, 8, 0]
    np.testing.assert_allclose(got[list(registry.OUTPUT_NAMES)].to_numpy(), expect, rtol=1e-9)
    # 2600 mL more stressed volume: the flagged row's pressures are those of a fuller circulation
    assert got.loc[1, "P_a_sys"] > got.loc[0, "P_a_sys"] + 100


def test_console_script_is_installed(tmp_path, default_params):
    exe = Path(sys.executable).parent / "cvsim6"
    src = tmp_path / "p.csv"
    pd.DataFrame([default_params], columns=registry.PARAMETER_NAMES).to_csv(src, index=False)
    res = subprocess.run([str(exe), "simulate", str(src), "-o", str(tmp_path / "o.csv")],
                         capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    got = pd.read_csv(tmp_path / "o.csv")
    assert abs(got.loc[0, "SVR"] - 1000 / 60 * 80) < 1e-6  # R_a = 1 mmHg·s/mL


def test_invert_round_trip(tmp_path):
    """Saved (untrained) networks in the workflow's layout; partial observations in."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    y = rng.normal(size=(300, 16)) * registry.noise_std() + 60
    v = rng.normal(size=(300, 23)) + 10
    emu = networks.Emulator(80, 8)
    emu.x_scaler.fit(v)
    emu.y_scaler.fit(y)
    flow = networks.RealNVP(hidden=18, blocks=10, layers_per_block=4, batchnorm=True)
    flow.y_scaler.fit(y)
    ed = networks.EncoderDecoder()
    ed.x_scaler.fit(v)
    ed.y_scaler.fit(y)
    models = tmp_path / "models"
    networks.save_model(emu, models / "emulator.pt")
    networks.save_model(flow.eval(), models / "flow_delta0.5.pt")
    networks.save_model(ed, models / "encoder_decoder_delta0.5.pt")
    obs = pd.DataFrame({"patient": ["p1", "p2"], "Hr": [70.0, 95.0], "P_a_sys": [120.0, None],
                        "CO": [5.0, 4.0]})
    src = tmp_path / "obs.csv"
    obs.to_csv(src, index=False)
    out = tmp_path / "params.csv"
    code = cli.main(["invert", str(src), "-o", str(out), "--models", str(models), "--samples", "7",
                     "--flow-samples", "5000", "--reference-size", "5"])
    assert code == 0
    got = pd.read_csv(out)
    assert len(got) == 14 and list(got["patient"].unique()) == ["p1", "p2"]
    assert set(registry.PARAMETER_NAMES) <= set(got.columns)
    assert {f"pred_{n}" for n in registry.OUTPUT_NAMES} <= set(got.columns)
    # observed entries are kept in the completion; missing ones are filled in
    p1 = got[got["patient"] == "p1"].iloc[0]
    assert p1["completed_Hr"] == 70.0 and p1["completed_CO"] == 5.0
    assert np.isfinite(got["completed_P_a_sys"]).all()
    assert got.groupby("patient")["ood_percentile"].nunique().eq(1).all()
    assert got["ood_percentile"].between(0, 100).all()
    # emulated outputs are those of the saved emulator on the sampled parameters
    np.testing.assert_allclose(got[[f"pred_{n}" for n in registry.OUTPUT_NAMES]].to_numpy(),
                               emu.predict(got[list(registry.PARAMETER_NAMES)].to_numpy()), rtol=1e-5, atol=1e-4)


def test_invert_errors(tmp_path, capsys):
    src = tmp_path / "obs.csv"
    pd.DataFrame({"Hr": [70.0]}).to_csv(src, index=False)
    assert cli.main(["invert", str(src), "-o", str(tmp_path / "o.csv"), "--models", str(tmp_path)]) == 2
    assert "model file(s) not found" in capsys.readouterr().err


# ----------------------------------------------------------------------------- invert: bad input
@pytest.fixture(scope="module")
def ehr_models(tmp_path_factory):
    """Small networks on 400 simulated EHR-prior sets (conftest.toy_ehr_networks: the flow is the
    Gaussian of the standardized outputs), saved in the workflow's layout, and those outputs as a
    --reference split. The decoder's C_a is centred on 0, so that decoded sets fall on both sides
    of the model's domain."""
    flow, ed, emu, v, y = toy_ehr_networks(400, 5)
    with torch.no_grad():
        ed.x_scaler.mean[registry.PARAMETER_INDEX["C_a"]] = 0.0
    root = tmp_path_factory.mktemp("ehr_models")
    networks.save_model(emu, root / "emulator.pt")
    networks.save_model(flow, root / "flow_delta0.5.pt")
    networks.save_model(ed, root / "encoder_decoder_delta0.5.pt")
    df = pd.DataFrame(v, columns=registry.PARAMETER_NAMES)
    for j, name in enumerate(registry.OUTPUT_NAMES):  # Hr is both: the output copies the input
        df[name] = y[:, j]
    datasets.write_dataset(df, root / "reference.parquet")
    return root, emu, y


FAST = ["--samples", "6", "--flow-samples", "4096", "--reference-size", "50"]

INVERT_BAD = {  # name: (file text, stderr line after "error: FILE")
    "LVEF in percent": ("patient,Hr,CO,LVEF\np1,70,5,0.55\np2,80,4,55\np3,90,4,60\n",
                        ": LVEF is a fraction (0-1); got 55 in line 3 (patient p2): percent? (2 such values of LVEF)"),
    "LVEF in percent, no patient column": ("Hr,LVEF\n70,62\n", ": LVEF is a fraction (0-1); got 62 in line 2: percent?"),
    "SVR in Wood units": ("Hr,CO,SVR\n70,5,15\n",
                          ": SVR is in dyn·s/cm^5 (50 to 10000); got 15 in line 2: Wood units (mmHg·min/L)? "
                          "1 WU = 80 dyn·s/cm^5"),
    "CO in mL/min": ("Hr,CO\n70,5\n72,5200\n", ": CO is in L/min (0.1 to 50); got 5200 in line 3: mL/min?"),
    "Hr in Hz": ("Hr,CO\n1.2,5\n", ": Hr is in bpm (10 to 400); got 1.2 in line 2: beats per second? "
                                   "(Hr is in beats per minute)"),
    "negative volume": ("V_l_dia,LVEF\n-120,0.5\n", ": V_l_dia is in mL (2 to 1000); got -120 in line 2"),
    "text in a cell": ("Hr,CO\n70,5\n,\n80,abc\n", ": line 4, column CO: 'abc' is not a number"),
    "header only": ("patient,Hr,CO\n", ": no patients (the file has a header only)"),
    "empty file": ("", ": the file is empty (no header, no rows)"),
    "unknown column": ("Hr,CO,P_a_sy\n70,5,100\n", ": line 1: unknown column(s) 'P_a_sy'; expected 'patient' and any "
                       "of the 16 outputs " + ", ".join(registry.OUTPUT_NAMES)),
    "repeated patient": ("patient,Hr,CO\np1,70,5\np2,70,5\np1,80,4\n",
                         ": line 4, column patient: patient 'p1' appears twice (also line 2)"),
    "blank patient name": ("patient,Hr,CO\np1,70,5\n,80,4\n", ": line 3, column patient: blank patient name"),
}


@pytest.mark.parametrize("case", list(INVERT_BAD))
def test_invert_bad_input_is_one_line_and_exit_2(case, tmp_path, ehr_models, capsys):
    text, expected = INVERT_BAD[case]
    src = tmp_path / "obs.csv"
    src.write_text(text)
    out = tmp_path / "params.csv"
    assert cli.main(["invert", str(src), "-o", str(out), "--models", str(ehr_models[0]), *FAST]) == 2
    assert capsys.readouterr().err.splitlines() == [f"error: {src}{expected}"]
    assert not out.exists()


def test_invert_bad_options_and_files(tmp_path, ehr_models, capsys):
    models = str(ehr_models[0])
    src = tmp_path / "obs.csv"
    src.write_text("Hr,CO\n70,5\n")
    out = str(tmp_path / "o.csv")
    junk = tmp_path / "junk"
    junk.mkdir()
    for name in ("emulator.pt", "flow_delta0.5.pt", "encoder_decoder_delta0.5.pt"):
        (junk / name).write_bytes((Path(models) / name).read_bytes() if name != "emulator.pt" else b"not torch")
    cases = [
        (["--samples", "0"], "error: --samples 0 is below its minimum of 1"),
        (["--corrector-steps", "-1"], "error: --corrector-steps -1 is below its minimum of 0"),
        (["--reference", str(tmp_path / "none.parquet")], f"error: --reference {tmp_path / 'none.parquet'}: no such file"),
        (["--models", str(tmp_path / "nowhere")], None),
        (["--models", str(junk)], None),
    ]
    for extra, line in cases:
        assert cli.main(["invert", str(src), "-o", out, "--models", models, *FAST, *extra]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("error: ")
        if line is not None:
            assert err == [line]
    assert "model file(s) not found" in err[0] or "not a cvsim6 model file" in err[0]
    assert err[0].startswith(f"error: {junk / 'emulator.pt'}: not a cvsim6 model file (")
    assert not Path(out).exists()


# ----------------------------------------------------------------------------- invert: partial results
def test_invert_keeps_going_past_a_blank_row(tmp_path, ehr_models, capsys):
    """An all-blank row is reported (status, stderr, exit 1); every other patient is inverted
    and written, with outputs far outside the training range named."""
    models, emu, y = ehr_models
    src = tmp_path / "obs.csv"
    # no patient column: rows are named by their line; line 3 is all blank, line 4 has Hr = 300 bpm
    src.write_text("Hr,P_a_sys,CO,LVEF\n70,120,5,0.55\n,,,\n300,110,4,0.6\n")
    out = tmp_path / "params.csv"
    code = cli.main(["invert", str(src), "-o", str(out), "--models", str(models), *FAST,
                     "--reference", str(models / "reference.parquet")])
    err = capsys.readouterr().err.splitlines()
    assert code == 1
    hr_lo, hr_hi = y[:, 0].min(), y[:, 0].max()
    pad = 0.1 * (hr_hi - hr_lo)
    assert err == [
        f"warning: {src}: line 3: not inverted: no output given",
        f"warning: {src}: line 4: Hr = 300 bpm is far outside the training range [{hr_lo - pad:.4g}, {hr_hi + pad:.4g}] "
        "bpm: its inversion extrapolates",
        f"inverted 2 of 3 patient(s) x 6 samples -> {out}; not inverted: line 3 (see the status column)",
    ]
    got = pd.read_csv(out, keep_default_na=False, na_values=[""])
    assert list(got["patient"]) == [0] * 6 + [1] + [2] * 6
    assert list(got["status"]) == ["ok"] * 6 + ["not inverted: no output given"] + ["ok"] * 6
    blank = got[got["patient"] == 1].iloc[0]
    assert np.isnan(blank["draw"]) and np.isnan(blank["C_a"]) and np.isnan(blank["ood_percentile"])
    assert list(got.groupby("patient")["outside_training"].first().fillna("")) == ["", "", "Hr"]
    ok = got[got["status"] == "ok"]
    assert list(ok["draw"]) == list(range(6)) * 2
    # the inverted patients are complete: observed entries kept, emulated outputs of their parameters
    assert (ok.loc[ok["patient"] == 2, "completed_Hr"] == 300).all()
    assert (ok.loc[ok["patient"] == 0, "completed_CO"] == 5).all()
    np.testing.assert_allclose(ok[[f"pred_{n}" for n in registry.OUTPUT_NAMES]].to_numpy(),
                               emu.predict(ok[list(registry.PARAMETER_NAMES)].to_numpy()), rtol=1e-5, atol=1e-4)
    assert (ok["ood_reference_size"] == 50).all()


def test_invert_flags_decoded_sets_outside_the_domain(tmp_path, ehr_models, capsys):
    models = ehr_models[0]
    src = tmp_path / "obs.csv"
    src.write_text("patient,Hr,P_a_sys,CO\nanna,70,120,5\n")
    out = tmp_path / "params.csv"
    assert cli.main(["invert", str(src), "-o", str(out), "--models", str(models), "--samples", "40",
                     "--flow-samples", "4096", "--reference-size", "20", "--corrector-steps", "0"]) == 0
    got = pd.read_csv(out)
    dom = model.outside_domain(got[list(registry.PARAMETER_NAMES)].to_numpy())
    assert 0 < dom.sum() < 40  # C_a is centred on 0 in this decoder: both kinds of draw occur
    assert np.array_equal(got["outside_domain"].to_numpy(bool), dom)
    assert np.array_equal(dom, (got["C_a"] <= 0).to_numpy())
    assert (got.loc[dom, "draw_status"] == solver.STATUS_REASONS[7]).all()
    assert set(got.loc[~dom, "draw_status"]) <= {"ok", solver.STATUS_REASONS[8]}
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (f"warning: {src}: line 2 (patient anna): {dom.sum()} of 40 decoded parameter sets are outside "
                      "the model's domain (see outside_domain)")


class DrawRecorder:
    """A flow that keeps every batch it samples (``draws``); everything else is the flow's."""

    def __init__(self, flow):
        self.flow, self.draws = flow, []

    def __getattr__(self, name):
        return getattr(self.flow, name)

    def sample_physical(self, n, generator=None):
        out = self.flow.sample_physical(n, generator=generator)
        self.draws.append(out)
        return out


def load_ehr_networks(models: Path) -> tuple:
    """(flow, encoder_decoder, emulator) saved in ``models`` at noise level 0.5, as the CLI loads them."""
    return tuple(networks.load_model(models / f) for f in ("flow_delta0.5.pt", "encoder_decoder_delta0.5.pt",
                                                            "emulator.pt"))


def test_invert_seed_reaches_every_draw(tmp_path, ehr_models):
    """Same --seed, same file, bit for bit (the OOD reference included, drawn from the flow);
    another seed, other reference draws."""
    models, _, y = ehr_models
    src = tmp_path / "obs.csv"
    src.write_text("Hr,P_a_sys,CO\n70,120,5\n")
    runs = {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        out = tmp_path / f"{name}.csv"
        assert cli.main(["invert", str(src), "-o", str(out), "--models", str(models), *FAST, "--seed", str(seed)]) == 0
        runs[name] = out.read_bytes()
    assert runs["a"] == runs["b"] and runs["a"] != runs["c"]
    # The library draws its flow reference from the seed too. A complete observation under this
    # Gaussian flow scores its own log-density, and so does each reference draw (nothing to
    # complete): its percentile is the share of the flow's reference draws, all of them kept
    # (n_reference = their number), whose Gaussian log-density is below the observation's.
    flow, ed, emu = load_ehr_networks(models)
    mean, std = flow.y_scaler.mean.double().numpy(), flow.y_scaler.std.double().numpy()
    obs = pd.DataFrame(y[[17]], columns=list(registry.OUTPUT_NAMES))
    own = gaussian_log_density(obs.to_numpy(), mean, std)[0]
    pct, draws = [], []
    for seed in (5, 5, 6):
        recorder = DrawRecorder(flow)
        got = ehr_study.invert_observations(obs, recorder, ed, emu, n_latent=2, n_flow_samples=4096, seed=seed,
                                            n_reference=ehr_study.REFERENCE_FLOW_DRAWS)
        assert [d.shape for d in recorder.draws] == [(ehr_study.REFERENCE_FLOW_DRAWS, 16)]  # the reference only
        assert got["log_density"].iloc[0] == pytest.approx(own, rel=1e-6)
        ref = gaussian_log_density(recorder.draws[0], mean, std)
        # float32 network against float64 arithmetic: a draw within 1e-3 nats may rank either way
        low, high = 100 * np.mean(ref < own - 1e-3), 100 * np.mean(ref < own + 1e-3)
        assert high - low <= 0.1
        assert low <= got["ood_percentile"].iloc[0] <= high
        pct.append(got["ood_percentile"].iloc[0])
        draws.append(recorder.draws[0])
    assert pct[0] == pct[1] and np.array_equal(draws[0], draws[1])
    assert not np.array_equal(draws[0], draws[2])
    assert 5 < pct[2] < 95  # a simulated patient, not an outlier of the fitted Gaussian


@pytest.mark.parametrize("reference", [False, True], ids=["flow-reference", "simulated-reference"])
def test_invert_equals_the_library_inversion(tmp_path, ehr_models, reference, capsys):
    """``cvsim6 invert`` writes what ``cvsim6.studies.ehr.invert_observations`` returns for the same
    observations, networks, seed and settings (to the 8 significant digits of its CSV); without
    --corrector-steps, what the library gives at its default."""
    models, _, y = ehr_models
    names = list(registry.OUTPUT_NAMES)
    obs = pd.DataFrame(y[[3, 8, 13]], columns=names, index=pd.Index(["p1", "p2", "p3"], name="patient"))
    obs.iloc[0, [2, 4, 6, 8, 10, 14, 15]] = np.nan  # the paper's missing set
    obs.iloc[1, 5:] = np.nan  # p2: the first five only; p3: everything observed
    src = tmp_path / "obs.csv"
    obs.to_csv(src, float_format="%.17g")
    out = tmp_path / "params.csv"
    options = ["--samples", "5", "--flow-samples", "3000", "--reference-size", "40", "--seed", "11"]
    corrector = {"corrector_steps": 1} if reference else {}  # else the defaults of both
    options += ["--reference", str(models / "reference.parquet"), "--corrector-steps", "1"] if reference else []
    assert cli.main(["invert", str(src), "-o", str(out), "--models", str(models), *options]) == 0
    capsys.readouterr()
    got = pd.read_csv(out, keep_default_na=False, na_values=[""])
    flow, ed, emu = load_ehr_networks(models)
    lib = ehr_study.invert_observations(obs, flow, ed, emu, n_latent=5, n_flow_samples=3000, seed=11,
                                        reference_outputs=y if reference else None, n_reference=40, **corrector)
    assert list(got.columns) == ["patient"] + list(lib.columns[1:])
    assert list(got["patient"]) == list(lib["id"]) == ["p1"] * 5 + ["p2"] * 5 + ["p3"] * 5
    for col in ("status", "draw_status"):
        assert list(got[col]) == list(lib[col]), col
    assert list(got["outside_training"].astype(object).fillna("")) == list(lib["outside_training"])
    assert list(got["outside_domain"]) == list(lib["outside_domain"])
    numbers = ["draw", *registry.PARAMETER_NAMES, *(f"pred_{n}" for n in names), *(f"completed_{n}" for n in names),
               "log_density", "ood_percentile", "ood_reference_size"]
    np.testing.assert_allclose(got[numbers].to_numpy(float), lib[numbers].to_numpy(float), rtol=1e-7, atol=0)
    assert (lib["ood_reference_size"] == 40).all()
    assert lib.groupby("id")["ood_percentile"].nunique().eq(1).all()


def test_simulate_warns_of_outputs_outside_their_physiological_range(tmp_path, default_params, capsys):
    """A compliance in CGS units (C_a = 0.0012 instead of 1.6 mL/mmHg) is simulated all the same,
    exit code 0, with a warning naming the row and each output outside its range."""
    P = np.repeat(default_params[None], 3, axis=0)
    P[1, registry.PARAMETER_INDEX["C_a"]] = 0.0012
    src = tmp_path / "params.csv"
    pd.DataFrame(P, columns=registry.PARAMETER_NAMES).to_csv(src, index=False, float_format="%.17g")
    out = tmp_path / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out)]) == 0
    got = pd.read_csv(out)
    assert (got["status"] == "ok").all()
    low, high = registry.PHYSIOLOGICAL_RANGE["P_a_dia"]
    assert not low <= got.loc[1, "P_a_dia"] <= high  # a stiff aorta: the diastolic pressure falls
    outside = [n for n, (lo, hi) in registry.PHYSIOLOGICAL_RANGE.items() if not lo <= got.loc[1, n] <= hi]
    assert all(lo <= got.loc[r, n] <= hi for r in (0, 2) for n, (lo, hi) in registry.PHYSIOLOGICAL_RANGE.items())
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if line.startswith("warning:")]
    assert warnings == [f"warning: {src}: line 3: {n} = {got.loc[1, n]:.4g} outside its physiological range "
                        f"{registry.PHYSIOLOGICAL_RANGE[n][0]:g} to {registry.PHYSIOLOGICAL_RANGE[n][1]:g} "
                        "(parameters in clinical units?)" for n in outside]


def test_range_warnings_beyond_the_limit_are_counted_per_output(capsys):
    """Past the first ``limit`` warnings one line counts the rest per output, most frequent first."""
    n = 30
    result = pd.DataFrame({name: np.full(n, 0.5 * (lo + hi)) for name, (lo, hi) in registry.PHYSIOLOGICAL_RANGE.items()})
    result["status"] = "ok"
    result.loc[:, "CO"] = 50.0  # all 30 rows
    result.loc[:9, "Hr"] = 10.0  # rows 0-9
    result.loc[29, "status"] = "flagged"  # left to the status column
    cli._warn_unphysiological(result, "in.csv", np.arange(2, n + 2), limit=5)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 6
    # in row order (registry order within a row): row 0's Hr and CO, row 1's, then row 2's Hr
    assert [line.split(": ", 2)[2].split(" = ")[0] for line in err[:5]] == [
        "line 2: Hr", "line 2: CO", "line 3: Hr", "line 3: CO", "line 4: Hr"]
    # 29 CO + 10 Hr = 39 found, 5 shown (3 Hr, 2 CO): 34 more, CO 27, Hr 7
    assert err[5] == "warning: in.csv: 34 more output(s) outside their physiological range (CO 27, Hr 7)"
