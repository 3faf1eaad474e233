"""The cvsim6 command line: simulate round trip and input errors."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6 import cli, registry, solver


def test_simulate_round_trip(tmp_path, structural_sets):
    P = structural_sets[:4]
    df = pd.DataFrame(P, columns=registry.PARAMETER_NAMES)
    df = df[list(reversed(df.columns))]  # any column order
    df["patient"] = ["a", "b", "c", "d"]  # extra columns ignored
    src = tmp_path / "params.csv"
    df.to_csv(src, index=False, float_format="%.17g")
    out = tmp_path / "sub" / "out.csv"
    assert cli.main(["simulate", str(src), "-o", str(out)]) == 0
    got = pd.read_csv(out)
    assert list(got.columns) == list(registry.OUTPUT_NAMES) + ["status"]
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
    assert "row 2: parameter R_a = 0.0" in capsys.readouterr().err
    assert not out.exists()


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
    import torch

    from cvsim6 import networks

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
