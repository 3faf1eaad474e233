"""`snakemake --report` holds every table and figure of the workflow, each with a caption, in
categories numbered by paper section with the scorecard first; every caption file is used.

The report is built from a copy of the workflow whose outputs are empty placeholders, one per
output of a forced dry run of the targets ``all``, ``calibration`` and ``seeds``: Snakemake itself then
reads the ``report()`` flags, expands the categories and renders the captions, and no job runs
(about 10 s per network source on 2 cores).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from conftest import ROOT, copy_workflow, snakemake

TARGETS = ("all", "calibration", "seeds")
#: Network source -> the config arguments that select it (the default config trains them).
SOURCES = {"trained": (), "published": ("--configfile", "config/config.yaml", "config/published.yaml")}
#: Folders whose CSV files are tables: the Markdown file of the same name is the report's entry.
#: Other CSV files hold the data behind a figure.
TABLE_FOLDERS = {"tables", "report"}
SCORECARD = "results/report/reproduction.md"
#: Beside the scorecard: the spread of its headlines over seeds (target ``seeds``).
SPREAD_OVER_SEEDS = ["results/report/seeds.md", "results/report/seeds_best_delta.md"]
PUBLISHED_MARK = ", published networks"
CAPTION = re.compile(r'caption="\.\./report/([^"]+)"')


def dry_run_outputs(work: Path, config_args: tuple[str, ...]) -> dict[str, str]:
    """Output path -> rule, for every job of a forced dry run of TARGETS in ``work``."""
    proc = snakemake("-n", "--forceall", *TARGETS, *config_args, cwd=work)
    assert proc.returncode == 0, proc.stderr
    outputs, rule = {}, None
    for line in (proc.stdout + proc.stderr).splitlines():
        line = line.strip()
        named = re.match(r"(?:local)?rule (\w+):$", line)
        if named:
            rule = named.group(1)
        elif rule and line.startswith("output:"):
            outputs.update((path.strip(), rule) for path in line.split(":", 1)[1].split(","))
    assert outputs, proc.stdout
    return outputs


def report_variable(html: str, name: str):
    """The JSON value the report page assigns to ``var <name>`` in its script of that id."""
    found = re.search(r'<script id="%s">\s*var %s = (.*?);\s*</script>' % (name.replace("_", "-"), name),
                      html, re.S)
    assert found, f"no {name} in the report"
    return json.loads(found.group(1))


@pytest.fixture(scope="module", params=sorted(SOURCES))
def built(request, tmp_path_factory):
    """The report of one network source, built over placeholder outputs: its outputs (path ->
    rule), results (path -> entry), categories ({category: {subcategory: [paths]}}), front
    page (HTML) and Snakemake's output while building it."""
    source = request.param
    config_args = SOURCES[source]
    work = copy_workflow(tmp_path_factory.mktemp(f"report_{source}"))
    outputs = dry_run_outputs(work, config_args)
    for path in outputs:
        target = work / path
        if not target.suffix:  # a directory() output (the published networks' folder)
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.touch()
    page = work / "report.html"
    proc = snakemake("--report", str(page), *TARGETS, *config_args, cwd=work)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log
    html = page.read_text(encoding="utf-8")
    return dict(source=source, outputs=outputs, results=report_variable(html, "results"),
                categories=report_variable(html, "categories"), front=report_variable(html, "workflow_desc"),
                log=log)


def test_every_table_and_figure_is_in_the_report(built):
    """Each PNG figure and Markdown table a job writes is a report entry with a caption; a CSV
    table counts through its Markdown twin."""
    results, missing = built["results"], []
    for path, rule in built["outputs"].items():
        entry = path
        if path.endswith(".csv") and TABLE_FOLDERS & set(Path(path).parent.parts):
            entry = path[: -len(".csv")] + ".md"
        elif not path.endswith((".png", ".md")):
            continue
        if entry not in results:
            missing.append(f"{entry} (rule {rule})")
        elif not re.sub(r"<[^>]+>", "", results[entry]["caption"]).strip():
            missing.append(f"{entry} (rule {rule}): empty caption")
    assert not missing, "not in the report:\n" + "\n".join(sorted(set(missing)))


def test_categories_are_numbered_with_the_scorecard_first(built):
    categories = built["categories"]
    names = sorted(categories)
    assert all(re.match(r"[1-9] \S", name) for name in names), names
    assert names[0] == "1 Reproduction scorecard", names
    first = [p for paths in categories[names[0]].values() for p in paths]
    assert first == [SCORECARD, *SPREAD_OVER_SEEDS]
    # every report entry sits in exactly one (category, subcategory)
    placed = [p for subs in categories.values() for paths in subs.values() for p in paths]
    assert sorted(placed) == sorted(built["results"])


def test_published_results_are_marked(built):
    """Results of the published networks (under results/published/) carry the mark in their
    subcategory, and no other result does."""
    wrong = [f"{path}: {category} / {sub}"
             for category, subs in built["categories"].items() for sub, paths in subs.items() for path in paths
             if path.startswith("results/published/") != sub.endswith(PUBLISHED_MARK)]
    assert not wrong, "\n".join(wrong)
    assert any(p.startswith("results/published/") for p in built["results"]) == (built["source"] == "published")


def test_captions_and_front_page_render_cleanly(built):
    """No docutils error or warning from any caption or the front page, which names the source."""
    problems = [line for line in built["log"].splitlines() if re.search(r"\((?:WARNING|ERROR|SEVERE)/\d\)", line)]
    assert not problems, "\n".join(problems)
    assert f"<strong>{built['source']}</strong>" in built["front"]


def test_caption_files_exist_and_are_all_used():
    """Each caption a rule names exists, and every workflow/report/*.rst is a caption or the
    front page (no orphans)."""
    named = {m for path in (ROOT / "workflow" / "rules").glob("*.smk") for m in CAPTION.findall(path.read_text())}
    report_dir = ROOT / "workflow" / "report"
    assert not [n for n in named if not (report_dir / n).is_file()], named
    assert 'report: "workflow/report/workflow.rst"' in (ROOT / "Snakefile").read_text()
    on_disk = {p.name for p in report_dir.glob("*.rst")}
    assert on_disk - named == {"workflow.rst"}, sorted(on_disk - named)
