"""Per-rule CPU and wall seconds of a workflow run, from Snakemake's per-job benchmark files.

Every rule writes ``logs/benchmarks/<rule>.tsv`` or ``logs/benchmarks/<rule>/<wildcards>.tsv``
(Snakemake's ``benchmark:`` directive: wall seconds ``s``, CPU seconds ``cpu_time``, peak
memory ``max_rss`` in MB). This sums them per rule, largest CPU first, and gives the total:
where the CPU time of a ``snakemake --cores 2 all`` run went.

    .venv/bin/python benchmarks/workflow_times.py            # logs/benchmarks/ of this checkout
    .venv/bin/python benchmarks/workflow_times.py --root <other checkout>/logs/benchmarks --markdown

A file left from an earlier run of another rule set is counted too: run it on the
``logs/benchmarks/`` of a fresh clone for one run's figures.

Writes ``benchmarks/results/workflow_times.json`` (``--name``: another file, for another machine's
run beside it): the elapsed and busy wall time of each run, the per-rule table of each source (the
trained networks' run, and the published networks' where present) and every job, whatever
``--source`` and ``--jobs`` print.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

#: The workflow's per-job benchmark files of this checkout.
JOB_BENCHMARKS = Path(__file__).resolve().parents[1] / "logs" / "benchmarks"


def job_times(root: Path) -> pd.DataFrame:
    """One row per job: source (``trained``, or ``published`` for ``published/``, the
    run with the paper's networks), rule, job (wildcards), wall_s, cpu_s, max_rss_mb, and
    end_s: when the job ended (the file's modification time, seconds since the epoch)."""
    rows = []
    for tsv in sorted(root.rglob("*.tsv")):
        rel = tsv.relative_to(root)
        source = "trained"
        if rel.parts[0] == "published":  # a run with the published networks (config/published.yaml)
            source, rel = "published", rel.relative_to("published")
        rule, job = (rel.parts[0], rel.with_suffix("").as_posix().split("/", 1)[1]) if len(rel.parts) > 1 \
            else (rel.stem, "")
        df = pd.read_csv(tsv, sep="\t")
        if not {"s", "cpu_time", "max_rss"} <= set(df.columns) or df.empty:
            raise ValueError(f"{tsv}: not a Snakemake benchmark file (columns {list(df.columns)})")
        last = df.iloc[-1]  # a rule run with `repeat()` has one row per repeat; the last one counts
        rows.append(dict(source=source, rule=rule, job=job, wall_s=float(last["s"]), cpu_s=float(last["cpu_time"]),
                         max_rss_mb=float(last["max_rss"]), end_s=tsv.stat().st_mtime))
    if not rows:
        raise FileNotFoundError(f"no Snakemake benchmark files under {root}")
    return pd.DataFrame(rows)


def rule_times(jobs: pd.DataFrame) -> pd.DataFrame:
    """Per rule: jobs, CPU and wall seconds summed, the longest job's wall seconds, peak memory
    (MB); sorted by CPU seconds, with a final ``total`` row."""
    g = jobs.groupby("rule")
    table = pd.DataFrame({"jobs": g.size(), "cpu_s": g["cpu_s"].sum(), "wall_s": g["wall_s"].sum(),
                          "longest_wall_s": g["wall_s"].max(), "max_rss_mb": g["max_rss_mb"].max()})
    table = table.sort_values("cpu_s", ascending=False)
    table["cpu_share"] = table["cpu_s"] / table["cpu_s"].sum()
    total = pd.DataFrame({"jobs": [table["jobs"].sum()], "cpu_s": [table["cpu_s"].sum()],
                          "wall_s": [table["wall_s"].sum()], "longest_wall_s": [table["longest_wall_s"].max()],
                          "max_rss_mb": [table["max_rss_mb"].max()], "cpu_share": [1.0]}, index=["total"])
    return pd.concat([table, total]).rename_axis("rule").reset_index()


def run_spans(jobs: pd.DataFrame) -> pd.DataFrame:
    """Per source: jobs, CPU seconds, the elapsed wall time of its run from the first job's start
    (its end less its wall seconds) to the last job's end, and the busy wall time: the length of
    the union of the jobs' [start, end] intervals, which leaves out the gaps of a run stopped and
    resumed. In seconds and minutes. Valid for files that kept their modification times (not
    copied without them); a job killed before its end left no file, so its time is not counted."""
    jobs = jobs.assign(start_s=jobs["end_s"] - jobs["wall_s"])
    g = jobs.groupby("source", sort=False)
    span = pd.DataFrame({"jobs": g.size(), "cpu_s": g["cpu_s"].sum(), "elapsed_s": g["end_s"].max() - g["start_s"].min(),
                         "busy_s": g[["start_s", "end_s"]].apply(_union_length)})
    span["elapsed_min"] = span["elapsed_s"] / 60
    span["busy_min"] = span["busy_s"] / 60
    return span.rename_axis("source").reset_index()


def _union_length(intervals: pd.DataFrame) -> float:
    """Length of the union of the intervals [start_s, end_s] (seconds)."""
    total, reach = 0.0, -float("inf")
    for start, end in sorted(zip(intervals["start_s"], intervals["end_s"])):
        total += max(0.0, end - max(start, reach))
        reach = max(reach, end)
    return total


#: How the per-rule and per-job tables are shown (the page and ``--markdown``).
FORMATS = {"elapsed_s": ",.0f", "elapsed_min": ".1f", "busy_s": ",.0f", "busy_min": ".1f", "cpu_s": ",.0f",
           "wall_s": ",.0f", "longest_wall_s": ",.0f", "max_rss_mb": ",.0f", "cpu_share": ".1%"}


def main() -> None:
    import results_io

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=JOB_BENCHMARKS, help="the workflow's logs/benchmarks/ folder")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--jobs", action="store_true", help="one row per job instead of per rule")
    ap.add_argument("--source", choices=["trained", "published", "all"], default="trained",
                    help="which run's files: the trained networks' (default), the published ones', or both")
    ap.add_argument("--name", default="workflow_times",
                    help="result file name: benchmarks/results/<name>.json (another machine's run beside the default's)")
    results_io.add_note_argument(ap)
    args = ap.parse_args()
    run = results_io.Run()
    all_jobs = job_times(args.root)
    jobs = all_jobs.copy()
    if args.source == "all":
        jobs["rule"] = [r if s == "trained" else f"{s}/{r}" for s, r in zip(jobs["source"], jobs["rule"])]
    else:
        jobs = jobs[jobs["source"] == args.source]
    table = jobs.sort_values("cpu_s", ascending=False) if args.jobs else rule_times(jobs)
    shown = table.copy()
    for col, f in FORMATS.items():
        if col in shown:
            shown[col] = shown[col].map(("{:" + f.replace(",", "") + "}").format)
    print(shown.to_markdown(index=False) if args.markdown else shown.to_string(index=False))

    tables = [results_io.table(
        run_spans(all_jobs), "runs", "Per run (network source): its jobs, their CPU seconds, its elapsed wall "
        "time from the first job's start to the last job's end, and its busy wall time, the union of the jobs' "
        "intervals, which leaves out the gaps of a run stopped and resumed (from the files' modification times).",
        FORMATS)]
    for source in ("trained", "published"):
        part = all_jobs[all_jobs["source"] == source]
        if len(part):
            tables.append(results_io.table(
                rule_times(part), f"rules_{source}",
                f"Per rule, the {source} networks' jobs: CPU and wall seconds summed over the jobs, the longest "
                f"job's wall seconds, peak memory (MB) and share of the CPU seconds; largest first.", FORMATS))
    every = all_jobs.drop(columns="end_s").sort_values(["source", "rule", "job"]).reset_index(drop=True)
    tables.append(results_io.table(every, "jobs", "Every job: its wall and CPU seconds and peak memory (MB).",
                                   FORMATS, page=False))
    newest = max(p.stat().st_mtime for p in Path(args.root).rglob("*.tsv"))
    suffix = args.name.removeprefix("workflow_times").strip("_").replace("_", " ")
    run.save(
        args.name, "Workflow: CPU and wall seconds per rule" + (f" ({suffix})" if suffix else ""),
        "Where a run of the workflow spent its time: Snakemake's per-job benchmark files (the rules' "
        "benchmark: directive) summed per rule. Wall seconds are summed over the jobs, so they exceed "
        "the run's elapsed time when jobs ran side by side. The machine and load average of this section are "
        "the summary's, not the run's: the note, if any, says where the jobs ran.",
        tables, parameters={"root": Path(args.root).resolve(), "job_files": len(all_jobs),
                            "newest_job_file_utc": _utc(newest)}, note=args.note)


def _utc(timestamp: float) -> str:
    import datetime as dt

    when = dt.datetime.fromtimestamp(timestamp, dt.timezone.utc).replace(microsecond=0)
    return when.isoformat().replace("+00:00", "Z")


if __name__ == "__main__":
    main()
