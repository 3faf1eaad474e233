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
