"""Write docs/performance.md from the committed result files in benchmarks/results/, nothing else.

Every number on the page comes from a result file (see ``benchmarks/results_io.py`` for their
format); each section names its file, the command that wrote it, the date and the machine.
``tests/test_performance_page.py`` fails when the committed page differs from what this
renders, or when a result file is not on the page.

    .venv/bin/python benchmarks/performance_page.py            # rewrite docs/performance.md
    .venv/bin/python benchmarks/performance_page.py --check    # exit 1 when the page is stale
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "performance.md"
#: The command that rebuilds the page (shown on it).
COMMAND = ".venv/bin/python benchmarks/performance_page.py"

#: Order of the sections, by result-file name pattern; files matching none come last, by name.
ORDER = ("simulator*", "machine_speed*", "workflow_times*", "algorithm*", "inversion*", "training_*",
         "emulator_errors_*", "restart_basins*", "continuation_epochs*", "batched_copies*", "seed_spread*")
#: Result files the page expects, and how to write each when it is absent.
EXPECTED = {
    "simulator": ("the simulator's speed and accuracy against the reference solver",
                  ".venv/bin/python benchmarks/simulator.py"),
    "machine_speed": ("the training CPU seconds per epoch of each network of the default config",
                      ".venv/bin/python benchmarks/machine_speed.py"),
    "workflow_times": ("the CPU and wall seconds per rule of a full run of the workflow; after "
                       "`snakemake --cores 2 all` (and the published networks' run, "
                       "`--configfile config/published.yaml`) in a fresh clone",
                       ".venv/bin/python benchmarks/workflow_times.py"),
}
#: Rules that run Algorithm 1 (paper section 3.3.3), shown from a workflow_times file's jobs.
ALGORITHM_1_RULES = {"invert_ehr_patients": "the EHR patients, one job per noise level",
                     "structural_missing_data": "the structural study's missing-data example"}


def load(folder: Path = RESULTS) -> dict[str, dict]:
    """The result files of ``folder`` by name (file stem), in page order."""
    results = {p.stem: json.loads(p.read_text()) for p in sorted(Path(folder).glob("*.json"))}
    return dict(sorted(results.items(), key=lambda kv: (_rank(kv[0]), kv[0])))


def _rank(name: str) -> int:
    for i, pattern in enumerate(ORDER):
        if fnmatch.fnmatch(name, pattern):
            return i
    return len(ORDER)


def cell(value, spec: str | None = None) -> str:
    """One table cell: ``spec`` (a format spec) for a number when given, else integers as they
    are and other numbers to four significant digits; empty for a missing value."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, (int, float)):
        if spec:
            if spec.endswith("d") and isinstance(value, float) and value.is_integer():
                value = int(value)
            return format(value, spec)
        return str(value) if isinstance(value, int) else format(value, ".4g")
    if isinstance(value, (dict, list)):
        value = json.dumps(value)
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(columns: list[str], rows: list[list], formats: dict | None = None) -> str:
    formats = formats or {}
    lines = ["| " + " | ".join(columns) + " |", "| " + " | ".join("---" for _ in columns) + " |"]
    for row in rows:
        lines.append("| " + " | ".join(cell(v, formats.get(c)) for c, v in zip(columns, row)) + " |")
    return "\n".join(lines)


def _machine(m: dict) -> str:
    parts = [m.get("cpu") or "unknown CPU"]
    if m.get("logical_cpus"):
        usable = m.get("usable_cpus")
        shown = f" ({usable} usable)" if usable not in (None, m["logical_cpus"]) else ""
        parts.append(f"{m['logical_cpus']} logical CPUs{shown}")
    if m.get("memory_gb"):
        parts.append(f"{m['memory_gb']} GB memory")
    if m.get("os"):
        parts.append(m["os"])
    software = [f"Python {m['python']}"] if m.get("python") else []
    software += [f"{k} {v}" for k, v in (m.get("packages") or {}).items()]
    text = ", ".join(parts) + ("; " + ", ".join(software) if software else "")
    start, end = m.get("load_average_start"), m.get("load_average_end")
    if start or end:
        text += (f"; load average (1, 5, 15 min) {', '.join(map(str, start or []))} at the start and "
                 f"{', '.join(map(str, end or []))} at the end")
    return text


def section(name: str, r: dict) -> str:
    """A result file's section: where it came from, then its tables."""
    rel = f"benchmarks/results/{name}.json"
    out = [f"## {r.get('title', name)}", "",
           f"From [`{rel}`](../{rel}), written by `{r.get('script', '?')}` on {r.get('date', '?')}"
           + (f" at commit {r['commit']}" if r.get("commit") else "")
           + f" ({cell(r.get('wall_s'), ',.0f')} s wall):", "", "```bash", r.get("command", "?"), "```", "",
           f"Machine: {_machine(r.get('machine') or {})}."]
    if r.get("parameters"):
        out += ["", "Parameters: " + "; ".join(f"`{k}` {cell(v)}" for k, v in r["parameters"].items()) + "."]
    if r.get("note"):
        out += ["", f"Note: {r['note']}"]
    if r.get("description"):
        out += ["", r["description"]]
    kept = []
    for t in r.get("tables", []):
        if not t.get("page", True):
            kept.append(t)
            continue
        out += ["", f"Table `{t['name']}`: {t.get('caption', '')}", "",
                markdown_table(t["columns"], t["rows"], t.get("formats"))]
    if name.startswith("workflow_times"):
        out += _algorithm_1(r)
    for t in kept:
        out += ["", f"The file also holds the table `{t['name']}` ({len(t['rows'])} rows): {t.get('caption', '')}"]
    return "\n".join(out)


def _algorithm_1(r: dict) -> list[str]:
    """The jobs of the rules that run Algorithm 1, from the file's ``jobs`` table."""
    jobs = next((t for t in r.get("tables", []) if t["name"] == "jobs"), None)
    if jobs is None:
        return []
    col = {c: i for i, c in enumerate(jobs["columns"])}
    rows = [row for row in jobs["rows"] if row[col["rule"]] in ALGORITHM_1_RULES]
    if not rows:
        return []
    shown = ["source", "rule", "job", "cpu_s", "wall_s", "max_rss_mb"]
    rules = "; ".join(f"`{k}`: {v}" for k, v in ALGORITHM_1_RULES.items())
    return ["", f"Algorithm 1 (paper section 3.3.3), the jobs of the rules that run it ({rules}); from the "
                f"table `jobs` of the same file:", "",
            markdown_table(shown, [[row[col[c]] for c in shown] for row in rows], jobs.get("formats"))]


def render(folder: Path = RESULTS) -> str:
    """The page, from the result files of ``folder`` only."""
    results = load(folder)
    out = ["# Performance", "",
           f"Written by `{COMMAND}` from the result files in `benchmarks/results/`, which the scripts in "
           f"`benchmarks/` write (see [benchmarks/README.md](../benchmarks/README.md)); do not edit it by hand. "
           f"`tests/test_performance_page.py` fails when this page is not what the script renders from the "
           f"committed files. Speeds are ratios against a baseline measured in the same run; absolute seconds "
           f"depend on the machine and on its load, which each section gives."]
    missing = [(n, what, cmd) for n, (what, cmd) in EXPECTED.items() if n not in results]
    if results:
        out += ["", "Contents:", ""]
        out += [f"- [{r.get('title', n)}](#{_anchor(r.get('title', n))}) (`{n}.json`)" for n, r in results.items()]
    for name, r in results.items():
        out += ["", section(name, r)]
    if missing:
        out += ["", "## Not measured yet", ""]
        out += [f"- {what}: `{cmd}` writes `benchmarks/results/{n}.json`." for n, what, cmd in missing]
    others = sorted(p.name for p in Path(folder).iterdir() if p.is_file() and p.suffix != ".json") \
        if Path(folder).is_dir() else []
    if others:
        out += ["", "## Other files", ""]
        out += [f"- [`benchmarks/results/{f}`](../benchmarks/results/{f})" for f in others]
    return "\n".join(out) + "\n"


def _anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    keep = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return keep.replace(" ", "-")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when docs/performance.md is not the rendered page")
    args = ap.parse_args(argv)
    page = render()
    if args.check:
        if not PAGE.is_file() or PAGE.read_text() != page:
            print(f"{PAGE.relative_to(ROOT)} is stale: run {COMMAND}", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(page)
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
