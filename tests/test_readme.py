"""The README is true: every command it shows dry-runs (or, for the CLI, names real options),
every path it names exists or is produced by a rule, every config key is in the schema, every
rule produces the file its row names by the function it names, and it stays a short guide."""
from __future__ import annotations

import importlib
from concurrent.futures import ThreadPoolExecutor
import re
import shlex
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, SNAKEMAKE, snakemake
from test_workflow import rule_functions

README = (ROOT / "README.md").read_text()
SCHEMA = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
#: Placeholders the README uses for a user's own files.
USER_FILES = {"my-paths.yaml", "PARAMS.csv", "OUT.csv", "OBS.csv", "SAMPLES.csv", "report.zip"}
EXAMPLE_EHR = "/data/cvsim6/EHR_dataset.csv"
EXAMPLE_NETWORKS = "/data/cvsim6/paper_networks"


def fenced_blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def inline_code() -> list[str]:
    text = re.sub(r"```.*?```", "", README, flags=re.S)
    return re.findall(r"`([^`\n]+)`", text)


def commands(program: str) -> list[str]:
    """Every command line of ``program`` in the README, code blocks and inline code."""
    lines = [ln.strip() for block in fenced_blocks("bash") for ln in block.splitlines()]
    lines += inline_code()
    found = []
    for line in lines:
        for part in line.split("&&"):
            part = part.strip().removeprefix(".venv/bin/")
            if part.split(" ", 1)[0] == program:
                found.append(part)
    return list(dict.fromkeys(found))


# ----------------------------------------------------------------------------- shape
def test_readme_is_a_short_guide_without_history():
    assert len(README.splitlines()) <= 300
    assert "../shared" not in README and "/work/" not in README
    hashes = [h for h in re.findall(r"\b[0-9a-f]{7,40}\b", README) if re.search(r"[a-f]", h) and re.search(r"\d", h)]
    assert not hashes, f"commit hashes in the README: {hashes}"
    for section in ("## Quick start", "## Offline use", "## Where each result comes from", "## Configuration",
                    "## Command line", "## Cluster", "## Departures from the paper", "## Layout", "## Development"):
        assert section in README, section


def _busy_minutes(result: str, source: str = "trained") -> float:
    """Busy wall minutes of the committed timed run ``benchmarks/results/<result>.json`` of one
    network source (``benchmarks/workflow_times.py``: the union of its jobs' intervals)."""
    import json

    tables = json.loads((ROOT / "benchmarks" / "results" / f"{result}.json").read_text())["tables"]
    runs = next(t for t in tables if t["name"] == "runs")
    rows = [dict(zip(runs["columns"], r)) for r in runs["rows"]]
    return float(next(r["busy_min"] for r in rows if r["source"] == source))


def test_slow_machine_run_time_is_the_measured_one():
    """The Quick start's run time on a slow machine is that of the committed timed run there."""
    m = re.search(r"up to about (\d+) on a slow one", README)
    assert m, "the Quick start's run time on a slow machine"
    assert float(m[1]) * 60 == pytest.approx(_busy_minutes("workflow_times_second_machine"), rel=0.15)


def _one_digit(x: float) -> float:
    """``x`` to one significant digit, as the README states speed ratios ("about 4,000")."""
    return float(f"{x:.1g}")


def test_simulator_claims_are_the_committed_work_precision_measurement():
    """The simulator's speed and error claims are those of ``simulator_accuracy.json`` for the
    default config's steps per cycle."""
    import json

    m = re.search(r"about ([\d,]+) times the speed per core of an\s+adaptive Radau solver at the paper code's "
                  r"tolerance, with errors under (\d+)% of the measurement\s+noise, and about ([\d,]+) times its "
                  r"speed at equal accuracy", README)
    assert m, "the simulator's claim in the introduction"
    tables = {t["name"]: t for t in json.loads((ROOT / "benchmarks/results/simulator_accuracy.json").read_text())["tables"]}
    rows = {t: [dict(zip(tables[t]["columns"], r)) for r in tables[t]["rows"]] for t in tables}
    steps = yaml.safe_load((ROOT / "config/config.yaml").read_text())["simulator"]["steps_per_cycle"]
    default = next(r for r in rows["work_precision"] if r["setting"] == f"{steps} steps/cycle")
    assert float(m[1].replace(",", "")) == _one_digit(default["speed_vs_paper_rtol"])
    assert default["max_error_noise_sd"] < float(m[2]) / 100
    equal = next(r for r in rows["equal_accuracy"] if r["reference"] == "rtol 0.0001")
    assert float(m[3].replace(",", "")) == _one_digit(equal["speed_at_equal_accuracy"])


def test_test_command_is_what_ci_runs():
    pytest_cmd = next(c for c in commands("python") if "pytest" in c and "not slow" not in c)
    assert pytest_cmd in (ROOT / ".ci/run").read_text()
    setup = next(b for b in fenced_blocks("bash") if "pip install" in b).strip().splitlines()[0]
    for piece in setup.split("&&"):
        assert piece.strip().replace(" -q", "") in (ROOT / ".ci/run").read_text().replace(" -q", "")


# ----------------------------------------------------------------------------- commands
@pytest.fixture(scope="module")
def user_paths(tmp_path_factory) -> dict[str, str]:
    """Stand-ins for the README's example local copies (a dry run only checks that they exist)."""
    tmp = tmp_path_factory.mktemp("readme")
    (tmp / "EHR_dataset.csv").write_text("")
    (tmp / "paper_networks").mkdir()
    example = (ROOT / "config/offline.example.yaml").read_text()
    assert EXAMPLE_EHR in example and EXAMPLE_NETWORKS in example
    mine = tmp / "my-paths.yaml"
    mine.write_text(example.replace(EXAMPLE_EHR, str(tmp / "EHR_dataset.csv"))
                    .replace(EXAMPLE_NETWORKS, str(tmp / "paper_networks")))
    return {"my-paths.yaml": str(mine), EXAMPLE_EHR: str(tmp / "EHR_dataset.csv")}


def as_dry_run(command: str, user_paths: dict[str, str]) -> list[str] | None:
    """The README's snakemake command as a dry run (None for a report, built after a run)."""
    for placeholder, path in user_paths.items():
        command = command.replace(placeholder, path)
    args = shlex.split(command)[1:]
    if "--report" in args:
        return None
    if "--rulegraph" in args or "--lint" in args:
        return args  # these plan nothing
    return ["-n", *args]


def test_every_snakemake_command_dry_runs(user_paths):
    found = commands("snakemake")
    assert len(found) >= 10 and any("--report" in c for c in found)
    assert "--report" in subprocess.run([SNAKEMAKE, "--help"], capture_output=True, text=True).stdout
    runs = {c: args for c in found if (args := as_dry_run(c, user_paths)) is not None}
    with ThreadPoolExecutor(2) as pool:  # each dry run mostly waits on its own start-up
        procs = dict(zip(runs, pool.map(lambda a: snakemake(*a, timeout=300), runs.values())))
    failures = [f"{c}\n{p.stderr[-800:]}" for c, p in procs.items() if p.returncode != 0]
    assert not failures, "\n\n".join(failures)


@lru_cache
def cli_help(sub: str) -> str:
    proc = subprocess.run([str(Path(sys.executable).parent / "cvsim6"), sub, "--help"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_every_cli_option_exists():
    found = commands("cvsim6")
    assert {c.split()[1] for c in found} == {"simulate", "invert"}
    for command in found:
        sub = command.split()[1]
        for option in re.findall(r"(--[a-z-]+|-o)\b", command):
            assert re.search(rf"(^|[\s,\[]){re.escape(option)}\b", cli_help(sub)), f"cvsim6 {sub}: {option}"
        for choice in re.findall(r"--method ([a-z|]+)", command):
            for value in choice.split("|"):
                assert value in cli_help(sub)


# ----------------------------------------------------------------------------- paths and rules
@lru_cache
def planned_jobs() -> dict[str, dict[str, set[str]]]:
    """Rule -> {'output': ..., 'log': ..., 'benchmark': ...} over forced dry runs of every target,
    for both network sources (stand-in local copies for the published networks)."""
    jobs: dict[str, dict[str, set[str]]] = {}
    local = ROOT / ".pytest_cache" / "readme_local.yaml"
    local.parent.mkdir(exist_ok=True)
    (local.parent / "readme_networks").mkdir(exist_ok=True)
    local.write_text(yaml.safe_dump({"networks": {"published": {"path": str(local.parent / "readme_networks")}}}))
    for extra in ((), ("config/published.yaml", str(local))):
        proc = snakemake("-n", "--forceall", "all", "calibration", "seeds", "--configfile", "config/config.yaml", *extra)
        assert proc.returncode == 0, proc.stderr[-2000:]
        rule = None
        for line in proc.stdout.splitlines():
            if m := re.match(r"rule (\w+):$", line.strip()):
                rule = m.group(1)
            elif rule and (m := re.match(r"\s+(output|log|benchmark): (.*)$", line)):
                jobs.setdefault(rule, {}).setdefault(m.group(1), set()).update(p.strip() for p in m.group(2).split(","))
    return jobs


def produced(path: str) -> set[str]:
    """Rules whose outputs (or logs and benchmarks) are ``path`` or lie under it."""
    path = path.rstrip("/")
    return {rule for rule, kinds in planned_jobs().items()
            for files in kinds.values() for f in files if f == path or f.startswith(path + "/")}


def result_rows() -> list[list[str]]:
    """Rows of the table 'paper | file | rule | function'."""
    section = README.split("## Where each result comes from", 1)[1].split("\n## ", 1)[0]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in section.splitlines()
            if line.startswith("| ") and not line.startswith("| paper") and not line.startswith("| ---")]
    assert len(rows) >= 20
    return rows


def test_each_result_row_names_the_rule_and_function_that_make_its_files():
    functions = rule_functions()
    for paper, files, rule, function in result_rows():
        rule, function = rule.strip("`"), "cvsim6." + function.strip("`")
        assert functions.get(rule) == function, (paper, rule, function)
        module, name = function.split(":")
        assert callable(getattr(importlib.import_module(module), name))
        for f in re.findall(r"`([^`]+)`", files):
            assert rule in produced("results/" + f), (paper, f, rule)


def layout_paths() -> list[str]:
    block = README.split("## Layout", 1)[1].split("```", 2)[1]
    paths = []
    for line in block.splitlines():
        if not line.strip():
            continue
        token = line.split()[0]
        paths.append(("src/cvsim6/" + token) if line.startswith("  ") else token)
    return paths


def path_like(token: str) -> bool:
    return (" " not in token and not token.startswith("-") and "<" not in token and "{" not in token
            and ("/" in token or re.search(r"\.(md|csv|png|yaml|py|smk|txt|toml|rst|zip)$", token) is not None))


def test_every_path_exists_or_is_a_rule_output():
    tokens = [t for t in inline_code() if path_like(t)]
    rows = result_rows()
    tokens += ["results/" + f for row in rows for f in re.findall(r"`([^`]+)`", row[1])]
    tokens += layout_paths()
    assert "src/cvsim6/model/" in tokens and "results/report/reproduction.md" in tokens
    missing = []
    for token in dict.fromkeys(tokens):
        if token in USER_FILES or token.startswith("/data/") or token.startswith("results/") and not token[8:]:
            continue
        if (ROOT / token).exists() or (token.startswith(("results/", "logs/")) and produced(token)):
            continue
        if not token.startswith(("results/", "logs/")) and produced("results/" + token):
            continue  # a path relative to results/, as in the table of results
        missing.append(token)
    assert not missing, missing


def test_decision_records_named_exist():
    section = README.split("## Departures from the paper", 1)[1].split("\n## ", 1)[0]
    numbers = re.findall(r"`(\d{4})`", section)
    assert len(numbers) >= 5
    for n in numbers:
        assert list((ROOT / "docs/decisions").glob(f"{n}-*.md")), n


# ----------------------------------------------------------------------------- config keys
def schema_node(key: str) -> dict | None:
    """The schema of config key ``a.b.c`` (None if the schema has no such key)."""
    node = SCHEMA
    for part in key.split("."):
        while "$ref" in node:
            node = SCHEMA["$defs"][node["$ref"].rsplit("/", 1)[1]]
        if part in node.get("properties", {}):
            node = node["properties"][part]
        elif isinstance(node.get("additionalProperties"), dict):
            node = node["additionalProperties"]
        else:
            return None
    return node


def config_keys() -> list[str]:
    tops = set(SCHEMA["properties"])
    keys = [t for t in inline_code() if re.fullmatch(r"[a-z_]+(\.[a-z_0-9]+)*(: .*)?", t)
            and t.split(".")[0].split(":")[0] in tops]
    return [k.split(":")[0] for k in keys]


def test_every_config_key_is_in_the_schema():
    keys = config_keys()
    assert {"ehr_data.path", "networks.published.path", "training.studies.ehr.noise_levels", "seed"} <= set(keys)
    unknown = [k for k in keys if schema_node(k) is None]
    assert not unknown, unknown


def test_offline_example_is_a_valid_config(user_paths):
    from cvsim6.workflow import config as wconfig

    base = wconfig.load_config(ROOT / "config/config.yaml")
    override = yaml.safe_load(Path(user_paths["my-paths.yaml"]).read_text())
    merged = {**base, "ehr_data": {**base["ehr_data"], **override["ehr_data"]},
              "networks": {**base["networks"], "published": {**base["networks"]["published"],
                                                             **override["networks"]["published"]}}}
    wconfig.validate_config(merged)
    assert merged["ehr_data"]["path"].endswith("EHR_dataset.csv")


def test_python_names_import():
    for name in (t for t in inline_code() if re.fullmatch(r"cvsim6(\.\w+)+", t)):
        try:
            importlib.import_module(name)
        except ImportError:
            module, attr = name.rsplit(".", 1)
            assert hasattr(importlib.import_module(module), attr), name


def test_dotted_config_override_fails_as_the_readme_says():
    proc = snakemake("-n", "all", "--config", "ehr_data.path=x.csv", timeout=120)
    assert proc.returncode != 0 and "Invalid config definition" in proc.stderr + proc.stdout
