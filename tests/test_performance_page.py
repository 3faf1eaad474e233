"""docs/performance.md is what benchmarks/performance_page.py renders from the committed result
files in benchmarks/results/, and every one of those files is on it: the page cannot go stale,
and no number on it is typed by hand."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "performance.md"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_page_is_what_the_script_renders_from_the_committed_results():
    page = _load("performance_page")
    assert PAGE.read_text() == page.render(RESULTS), (
        "docs/performance.md is stale: run .venv/bin/python benchmarks/performance_page.py and commit it")


def test_every_result_file_is_on_the_page():
    text = PAGE.read_text()
    files = sorted(p.name for p in RESULTS.iterdir() if p.is_file())
    assert files, "no result files in benchmarks/results/"
    assert [f for f in files if f"benchmarks/results/{f}" not in text] == []


def _strings(x):
    if isinstance(x, str):
        yield x
    elif isinstance(x, dict):
        for k, v in x.items():
            yield from _strings(k)
            yield from _strings(v)
    elif isinstance(x, list):
        for v in x:
            yield from _strings(v)


@pytest.mark.parametrize("path", sorted(RESULTS.glob("*.json")), ids=lambda p: p.name)
def test_a_result_file_says_what_ran_where_and_when_and_names_no_path_outside_the_repository(path):
    r = json.loads(path.read_text())
    assert r["name"] == path.stem and r["title"] and r["date"]
    assert (ROOT / r["script"]).is_file() and r["command"].split(" ")[1] == r["script"]
    assert r["machine"]["cpu"] and r["machine"]["logical_cpus"] >= 1
    assert r["tables"]
    for t in r["tables"]:
        assert t["rows"] and all(len(row) == len(t["columns"]) for row in t["rows"]), t["name"]
        assert set(t["formats"]) <= set(t["columns"]), t["name"]
    for s in _strings(r):
        assert not s.startswith(("/", "~")) and "../" not in s and "/work/" not in s, s


def test_commands_show_paths_outside_the_repository_by_their_last_part_only():
    rio = _load("results_io")
    root = Path("/srv/checkout")
    assert rio.portable("/srv/other/benchmarks", root) == "<elsewhere>/benchmarks"
    assert rio.portable("/srv/checkout/config/paper.yaml", root) == "config/paper.yaml"
    assert rio.portable("seed2024=../run-a", root) == "seed2024=<elsewhere>/run-a"
    assert rio.portable("--root=/data/x", root) == "--root=<elsewhere>/x"
    for same in ("config/paper.yaml", "cosine={lr_schedule: cosine, lr_final: 0.0}", "--epochs", "3"):
        assert rio.portable(same, root) == same
    argv = ["/srv/checkout/benchmarks/workflow_times.py", "--root", "/srv/other/logs/benchmarks", "--note", "shared",
            "--note=again", "--markdown"]
    assert rio.command_line(argv, root).split(" ", 1)[1] == (
        "benchmarks/workflow_times.py --root '<elsewhere>/benchmarks' --markdown")


def test_the_page_renders_any_result_file_and_says_how_to_write_the_missing_ones(tmp_path, capsys):
    rio, page = _load("results_io"), _load("performance_page")
    empty = page.render(tmp_path)
    assert "## Not measured yet" in empty
    for name in ("simulator", "machine_speed", "workflow_times"):
        assert f"benchmarks/{name}.py" in empty and f"benchmarks/results/{name}.json" in empty

    run = rio.Run([str(ROOT / "benchmarks" / "simulator.py"), "--n-batch", "10", "--note", "shared machine"])
    speed = pd.DataFrame({"path": ["batch", "reference"], "sets_per_cpu_s": [2000.0, 0.08],
                          "speed_vs_reference": [25000.0, 1.0]})
    curve = pd.DataFrame({"epoch": [1, 2], "loss": [float("nan"), 0.5]})
    run.save("simulator", "Simulator", "What it measures.",
             [rio.table(speed, "speed", "Speed.", {"speed_vs_reference": ",.0f"}),
              rio.table(curve, "curve", "A curve.", page=False)], parameters={"n_batch": 10}, note="shared machine",
             folder=tmp_path)
    saved = json.loads((tmp_path / "simulator.json").read_text())
    assert saved["tables"][1]["rows"][0] == [1, None]  # NaN is stored as null
    assert saved["command"].endswith("benchmarks/simulator.py --n-batch 10")
    text = page.render(tmp_path)
    assert "(../benchmarks/results/simulator.json)" in text and "Note: shared machine" in text
    assert "| batch | 2000 | 25,000 |" in text and "| reference | 0.08 | 1 |" in text
    assert "the table `curve` (2 rows)" in text and "| 1 |  |" not in text
    assert "benchmarks/results/simulator.json`." not in text  # no longer listed as missing
