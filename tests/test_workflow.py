"""The Snakemake workflow: dry runs, lint, config validation, and real runs of the table rules."""
from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
import yaml

from conftest import ROOT, copy_workflow, snakemake
from cvsim6 import registry

CALL_PY = ROOT / "workflow" / "scripts" / "call.py"
TABLE_TARGETS = [
    "results/tables/input_parameters.csv",
    "results/tables/input_parameters.md",
    "results/tables/output_parameters.csv",
    "results/tables/output_parameters.md",
]


@pytest.mark.parametrize("configfile", [None, "config/smoke.yaml", "config/paper.yaml"])
def test_dry_run(configfile):
    args = ["-n", "--forceall", "all"] + (["--configfile", configfile] if configfile else [])
    proc = snakemake(*args)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout + proc.stderr
    assert "input_parameter_table" in out and "output_parameter_table" in out


def test_dry_run_with_profiles():
    for profile in ("local", "slurm"):
        proc = snakemake("-n", "--forceall", "--workflow-profile", f"workflow/profiles/{profile}", "all")
        assert proc.returncode == 0, proc.stderr


def test_lint_is_clean():
    proc = snakemake("--lint")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "Lints for" not in out, out
    assert "good condition" in out


def bad_config(tmp_path: Path) -> Path:
    """The smoke config with a misspelled key in the simulator section."""
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["simulator"]["stepz_per_cycle"] = 300
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(cfg))
    return bad


def test_unknown_config_key_fails_dry_run(tmp_path):
    # Targets go before --configfile/--config: those options take several values.
    proc = snakemake("-n", "all", "--configfile", str(bad_config(tmp_path)))
    out = proc.stdout + proc.stderr  # a dry run logs to stdout
    assert proc.returncode != 0
    assert "Error validating config file" in out
    assert "'stepz_per_cycle' was unexpected" in out
    assert "rule input_parameter_table" not in out


def test_unknown_config_key_fails_before_any_job(tmp_path):
    work = copy_workflow(tmp_path / "work")
    proc = snakemake("--cores", "1", "all", "--configfile", str(bad_config(tmp_path)), cwd=work)
    assert proc.returncode != 0
    assert "stepz_per_cycle" in proc.stderr
    assert not (work / "results").exists()
    assert not (work / "logs").exists()


def test_wrong_config_type_fails():
    proc = snakemake("-n", "all", "--config", "seed=abc")
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "'abc' is not of type 'integer'" in out
    assert "seed" in out


@pytest.mark.slow
def test_table_rules_end_to_end(tmp_path):
    work = copy_workflow(tmp_path)
    proc = snakemake("--cores", "1", *TABLE_TARGETS, "--configfile", "config/smoke.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr

    inputs = pd.read_csv(work / "results/tables/input_parameters.csv").set_index("Name")
    assert tuple(inputs.index) == registry.PARAMETER_NAMES
    assert inputs.loc["C_l_dia", "Default (CGS)"] == pytest.approx(7.50e-3, rel=2e-3)
    assert inputs.loc["R_a", "Default (CGS)"] == pytest.approx(1333.22)
    assert inputs.loc["C_pa", "Default (CGS)"] == pytest.approx(3.23e-3, rel=2e-3)
    outputs = pd.read_csv(work / "results/tables/output_parameters.csv")
    assert list(outputs["Noise std"]) == [3.0, 1.5, 1.5, 1, 1, 1, 1, 1, 1, 0.5, 10, 20, 0.02, 0.2, 50, 5]  # paper table 2
    md = (work / "results/tables/input_parameters.md").read_text(encoding="utf-8")
    assert sum(line.startswith("|") for line in md.splitlines()) == 2 + 23

    for rule in ("input_parameter_table", "output_parameter_table"):
        log = (work / "logs" / f"{rule}.log").read_text()
        assert f"rule {rule}: done" in log
        assert (work / "logs" / "benchmarks" / f"{rule}.tsv").is_file()

    # Up to date now; a change to the package code makes both tables stale.
    proc = snakemake("-n", *TABLE_TARGETS, "--configfile", "config/smoke.yaml", cwd=work)
    assert "Nothing to be done" in proc.stdout + proc.stderr
    with open(work / "src/cvsim6/reporting/tables.py", "a") as fh:
        fh.write("\n# changed\n")
    proc = snakemake("-n", *TABLE_TARGETS, "--configfile", "config/smoke.yaml", cwd=work)
    out = proc.stdout + proc.stderr
    assert "Updated input files: src/cvsim6/reporting/tables.py" in out
    assert "input_parameter_table" in out and "output_parameter_table" in out


PROBE_MODULE = '''
import json, sys

def probe(single, many, out, number, threads):
    print("to stdout")
    print("to stderr", file=sys.stderr)
    with open(out, "w") as fh:
        json.dump({"single": single, "many": many, "out": out, "number": number, "threads": threads}, fh)

def no_threads(out):
    open(out, "w").close()

def fails(out):
    raise RuntimeError("probe failure")
'''

PROBE_SNAKEFILE = '''
rule probe:
    input:
        code="probe.py",
        single="a.txt",
        many=["a.txt", "b.txt"],
    output:
        out="probe.json",
    params:
        function="probe:probe",
        number=3,
    threads: 2
    log:
        "probe.log",
    script:
        "{call}"

rule no_threads:
    output:
        out="no_threads.txt",
    params:
        function="probe:no_threads",
    log:
        "no_threads.log",
    script:
        "{call}"

rule fails:
    output:
        out="fails.txt",
    params:
        function="probe:fails",
    log:
        "fails.log",
    script:
        "{call}"
'''


@pytest.mark.slow
def test_call_adapter(tmp_path):
    (tmp_path / "probe.py").write_text(PROBE_MODULE)
    (tmp_path / "Snakefile").write_text(textwrap.dedent(PROBE_SNAKEFILE).format(call=CALL_PY))
    (tmp_path / "a.txt").write_text("a")
    (tmp_path / "b.txt").write_text("b")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}

    proc = snakemake("--cores", "2", "probe.json", "no_threads.txt", cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    got = json.loads((tmp_path / "probe.json").read_text())
    assert got == {"single": "a.txt", "many": ["a.txt", "b.txt"], "out": "probe.json", "number": 3, "threads": 2}
    log = (tmp_path / "probe.log").read_text()
    assert "to stdout" in log and "to stderr" in log
    assert "INFO call: rule probe: probe:probe(" in log
    assert (tmp_path / "no_threads.txt").is_file()

    proc = snakemake("--cores", "1", "fails.txt", cwd=tmp_path, env=env)
    assert proc.returncode != 0
    log = (tmp_path / "fails.log").read_text()
    assert "ERROR call: rule fails: probe:fails failed" in log
    assert "Traceback" in log and "RuntimeError: probe failure" in log


def test_snakemake_files_are_formatted():
    """snakefmt, as the Snakemake workflow catalog checks it (fix with `snakefmt Snakefile workflow/`)."""
    proc = subprocess.run([str(Path(sys.executable).parent / "snakefmt"), "--check", "Snakefile", "workflow/"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def rule_functions() -> dict[str, str]:
    """Rule name (a regex for rules named in a loop) -> the ``module:function`` it calls."""
    found = {}
    for path in sorted((ROOT / "workflow" / "rules").glob("*.smk")):
        for block in re.split(r"(?m)^\s*rule\b", path.read_text())[1:]:
            function = re.search(r'function="([^"]+)"', block)
            if not function:
                continue
            named = re.match(r"\s*(\w+):", block)
            if named:
                name = named.group(1)
            else:  # rule: name: f"prefix_{var}"
                pattern = re.search(r'name:\s*f?"([^"]+)"', block).group(1)
                name = re.sub(r"\\\{[^}]*\\\}", ".+", re.escape(pattern))
            found[name] = function.group(1)
    return found


def dry_run_inputs(*config_args: str) -> dict[str, set[str]]:
    """Rule name -> union of the inputs of its jobs in a forced dry run of ``all``."""
    proc = snakemake("-n", "--forceall", "all", *config_args)
    assert proc.returncode == 0, proc.stderr
    inputs, rule = {}, None
    for line in (proc.stdout + proc.stderr).splitlines():
        m = re.match(r"rule (\w+):$", line.strip())
        if m:
            rule = m.group(1)
        elif rule and line.strip().startswith("input:"):
            inputs.setdefault(rule, set()).update(s.strip() for s in line.split(":", 1)[1].split(","))
    return inputs


def imported_package_files(module: str) -> set[str]:
    """Package source files loaded by importing ``module`` in a fresh interpreter."""
    code = ("import importlib, sys; importlib.import_module(sys.argv[1]); "
            "print('\\n'.join(m.__file__ for n, m in sys.modules.items() "
            "if n == 'cvsim6' or n.startswith('cvsim6.')))")
    proc = subprocess.run([sys.executable, "-c", code, module], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return {str(Path(f).resolve().relative_to(ROOT)) for f in proc.stdout.split()}


@pytest.mark.slow
def test_every_rule_reruns_when_code_it_imports_changes():
    """Each rule's `code` inputs hold every package file its function's module imports,
    measured by importing it (package imports are at module level: see the next test)."""
    functions = rule_functions()
    checked = set()
    closures = {}
    for config_args in ((), ("--configfile", "config/published.yaml")):
        for rule, inputs in dry_run_inputs(*config_args).items():
            name = next((n for n in functions if re.fullmatch(n, rule)), None)
            if name is None:
                continue  # `all`, and downloads (checked against a fixed SHA-256, not code)
            module = functions[name].split(":")[0]
            if module not in closures:
                closures[module] = imported_package_files(module)
            missing = closures[module] - inputs
            assert not missing, f"rule {rule} ({functions[name]}) does not declare {sorted(missing)}"
            checked.add(rule)
    assert {"structural_inversion_table", "invert_ehr_patients", "convert_published_ehr",
            "train_encoder_decoder", "reproduction_scorecard"} <= checked
    # the case that was stale before: table 3 decodes through inversion.py and simulates with the solver
    assert {"src/cvsim6/inference/inversion.py", "src/cvsim6/model/solver.py", "src/cvsim6/model/_kernel.py"} <= \
        closures["cvsim6.studies.structural"]


def test_package_imports_sit_at_module_level():
    """An import of a package module inside a function hides a dependency from the test above.
    The one exception is the CLI, whose commands import the solver and the networks late so
    that ``cvsim6 --help`` starts at once: no rule calls it."""
    assert not any(f.startswith("cvsim6.cli:") for f in rule_functions().values())
    hidden = []
    for path in sorted((ROOT / "src" / "cvsim6").rglob("*.py")):
        if path.relative_to(ROOT / "src" / "cvsim6").as_posix() == "cli.py":
            continue
        tree = ast.parse(path.read_text())
        for func in (n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))):
            for node in ast.walk(func):
                if isinstance(node, ast.ImportFrom) and (node.level > 0 or (node.module or "").startswith("cvsim6")):
                    hidden.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    assert not hidden, hidden
