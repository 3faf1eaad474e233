"""The result files of the benchmark scripts: one JSON file per script and measurement.

Every script in ``benchmarks/`` ends by writing ``benchmarks/results/<name>.json`` (committed),
which ``benchmarks/performance_page.py`` renders into ``docs/performance.md``. A file holds:

- ``name``, ``title``, ``description``: what was measured (the page's section);
- ``script`` and ``command``: the script, and the command line that wrote the file (paths
  outside the repository shown as ``<elsewhere>/<last part>``, ``--note`` left out);
- ``commit``: the checkout's commit (``+ uncommitted changes`` when tracked files differ from it);
- ``date`` (UTC, when the measurement started), ``wall_s`` (the script's wall seconds),
  ``machine`` (CPU model, logical CPUs, memory, OS, Python and package versions, the load
  average at start and end: a shared machine shows there), ``note`` (``--note``, free text);
- ``parameters``: the script's arguments and other settings of the measurement;
- ``tables``: a list of ``{"name", "caption", "columns", "rows", "formats", "page"}``; ``formats``
  maps a column to a Python format spec for the page (e.g. ``".1%"``); ``page`` false keeps a long
  table (a curve, every job) in the file only. Raw numbers, never rounded.

A script imports this module inside ``main()`` (``benchmarks/`` is on the path when a script runs),
so that tests can load a script's functions without it.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Where the result files go (committed).
RESULTS = ROOT / "benchmarks" / "results"
#: Packages whose versions a result file records.
PACKAGES = ("numpy", "pandas", "torch", "numba")


def add_note_argument(parser) -> None:
    """``--note TEXT``: free text stored in the result file and shown on the page."""
    parser.add_argument("--note", default="", help="free text for the result file (e.g. that the machine was shared)")


def machine() -> dict:
    """The machine and software a measurement ran on."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory_gb = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                memory_gb = round(int(line.split()[1]) / 1024**2, 1)
                break
    except (OSError, ValueError):
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    versions = {}
    for pkg in PACKAGES:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return {"cpu": cpu, "logical_cpus": os.cpu_count(), "usable_cpus": usable, "memory_gb": memory_gb,
            "os": f"{platform.system()} {platform.release()}", "python": platform.python_version(),
            "packages": versions}


def portable(token: str, root: Path = ROOT) -> str:
    """A command-line token with any path outside the repository shown as ``<elsewhere>/<name>``
    and any absolute path inside it made relative; ``NAME=PATH`` and ``--opt=PATH`` keep their
    prefix. Other tokens are returned as they are."""
    prefix, value = "", token
    if "=" in token:
        head, _, tail = token.partition("=")
        if head and not any(c in head for c in " /{:'\""):
            prefix, value = head + "=", tail
    looks_like_path = value.startswith(("/", "~", "../")) or value == ".."
    if not looks_like_path:
        return token
    path = Path(os.path.abspath(os.path.expanduser(value)))
    try:
        return prefix + path.relative_to(root).as_posix()
    except ValueError:
        return prefix + f"<elsewhere>/{path.name}"


def command_line(argv: list[str] | None = None, root: Path = ROOT) -> str:
    """The command that ran, as typed in the repository root: ``.venv/bin/python`` when the
    interpreter is the repository's virtual environment (else ``python``), the script relative to
    the root, the arguments with :func:`portable` paths, without ``--note`` (stored apart)."""
    argv = list(sys.argv if argv is None else argv)
    kept, skip = [], False
    for a in argv:  # the note is stored on its own
        if skip:
            skip = False
        elif a == "--note":
            skip = True
        elif not a.startswith("--note="):
            kept.append(a)
    argv = kept
    exe = Path(sys.executable)
    try:
        python = exe.relative_to(root).as_posix()
    except ValueError:
        python = "python"
    script = portable(str(Path(os.path.abspath(argv[0]))), root) if argv else ""
    return shlex.join([python, script, *(portable(a, root) for a in argv[1:])])


def commit(root: Path = ROOT) -> str | None:
    """The checkout's short commit, with `` + uncommitted changes`` when tracked files differ."""
    def git(*args):
        done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, check=True)
        return done.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + (" + uncommitted changes" if dirty else "")


def _plain(x):
    """JSON-ready: numpy scalars to Python, NaN and infinities to None."""
    if hasattr(x, "item") and not isinstance(x, (list, dict, str)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, Path):
        return portable(str(x))
    return x


def table(df, name: str, caption: str, formats: dict | None = None, index: bool = False, page: bool = True) -> dict:
    """A result table from a DataFrame (its index as the first column when ``index``); ``page``
    false: in the file only, the page names it."""
    if index:
        df = df.reset_index()
    return {"name": name, "caption": caption, "columns": [str(c) for c in df.columns],
            "rows": [[_plain(v) for v in row] for row in df.itertuples(index=False, name=None)],
            "formats": {c: f for c, f in (formats or {}).items() if c in df.columns}, "page": bool(page)}


class Run:
    """One measurement: started when made (date, wall clock, load average), written by :meth:`save`."""

    def __init__(self, argv: list[str] | None = None):
        self.started = time.perf_counter()
        self.date = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")
        self.command = command_line(argv)
        self.script = self.command.split(" ")[1] if " " in self.command else ""
        self.load_start = _load()
        self.commit = commit()

    def save(self, name: str, title: str, description: str, tables: list[dict], parameters: dict | None = None,
             note: str = "", folder: Path | None = None) -> Path:
        """Write ``<folder>/<name>.json`` (default ``benchmarks/results/``) and return its path."""
        folder = Path(folder or RESULTS)
        folder.mkdir(parents=True, exist_ok=True)
        info = machine()
        info["load_average_start"] = self.load_start
        info["load_average_end"] = _load()
        record = {"name": name, "title": title, "description": description, "script": self.script,
                  "command": self.command, "commit": self.commit, "date": self.date,
                  "wall_s": round(time.perf_counter() - self.started, 1), "machine": info, "note": note,
                  "parameters": _plain(parameters or {}), "tables": [_plain(t) for t in tables]}
        path = folder / f"{name}.json"
        path.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
        try:
            shown = path.resolve().relative_to(ROOT)
        except ValueError:
            shown = path
        print(f"wrote {shown}")
        return path


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None
