"""The package's shape guards what the layout promises: small modules and functions, and
computation that never imports the reporting layer (so editing a table's or a figure's look
reruns that table or figure only)."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

PACKAGE = ROOT / "src" / "cvsim6"
SOURCES = sorted(PACKAGE.rglob("*.py"))
#: Subpackages that compute: none of their modules may load cvsim6.reporting.
COMPUTING = ("model", "data", "nets", "training", "inference")


def module_name(path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def loaded_by_importing(modules: list[str], prefix: str) -> list[str]:
    """Sorted names in ``sys.modules`` starting with ``prefix`` after a fresh interpreter
    imports ``modules``."""
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"print(sorted(n for n in sys.modules if n.startswith({prefix!r})))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return ast.literal_eval(proc.stdout.strip())


def test_no_module_over_600_lines_and_no_function_over_100():
    long_modules = [f"{p.name}: {n}" for p in SOURCES if (n := len(p.read_text().splitlines())) > 600]
    long_functions = []
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if (n := node.end_lineno - node.lineno + 1) > 100:
                    long_functions.append(f"{module_name(path)}.{node.name}: {n}")
    assert not long_modules and not long_functions, (long_modules, long_functions)


def test_no_backend_chosen_anywhere():
    """matplotlib picks its backend itself: no matplotlib.use in the package."""
    offenders = [p.name for p in SOURCES if "matplotlib.use(" in p.read_text()]
    assert not offenders, offenders


@pytest.mark.parametrize("subpackage", COMPUTING)
def test_computation_does_not_import_reporting(subpackage):
    modules = [module_name(p) for p in SOURCES if p.relative_to(PACKAGE).parts[0] == subpackage]
    assert len(modules) >= 3
    loaded = loaded_by_importing(modules, "cvsim6.reporting")
    assert loaded == [], f"cvsim6.{subpackage} loads {loaded}"


def test_studies_import_no_figure_module():
    """The studies compute and write tables; figures are drawn by rules of their own."""
    modules = [module_name(p) for p in SOURCES if p.relative_to(PACKAGE).parts[0] == "studies"]
    loaded = loaded_by_importing(modules, "cvsim6.reporting")
    assert not [n for n in loaded if "figures" in n], loaded


def test_reference_posteriors_load_neither_sbi_nor_the_npe_code():
    """The MCMC references share their cases with the calibration stage, not its methods: a
    change to the NPE code does not rerun them, and their jobs do not import sbi."""
    from cvsim6.workflow.codegraph import module_closure

    closure = {Path(p).relative_to(PACKAGE).as_posix() for p in module_closure("studies.references", PACKAGE)}
    assert "studies/cases.py" in closure and "inference/reference_posterior.py" in closure
    assert not {"inference/npe.py", "studies/calibration.py", "inference/calibration.py"} & closure
    loaded = loaded_by_importing(["cvsim6.studies.references"], "sbi")
    assert loaded == [], loaded
