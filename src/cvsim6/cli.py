"""Command-line interface of the CVSim-6 digital twin.

``cvsim6 simulate PARAMS.csv -o OUT.csv``: PARAMS.csv has a header with the 23
parameter names (clinical units, any column order); OUT.csv has the input's other
columns (an id, say) first, then the 16 outputs plus ``status``, one row per input row,
in the same order. A simulated output outside its physiological range
(:data:`cvsim6.registry.PHYSIOLOGICAL_RANGE`) is kept, with a ``warning:`` line on stderr
naming the line and the output (a compliance in CGS units, say); the exit code is unchanged.

``cvsim6 invert OBS.csv -o PARAMS.csv``: OBS.csv has any subset of the 16 output
names as columns, one patient per row (blank = missing; an optional ``patient``
column names them); PARAMS.csv has, per patient, the sampled parameter sets with
their emulated outputs (``pred_*``) and the patient's out-of-distribution percentile.

Bad input. A problem with the input file or an option stops the command before anything
is computed or written, with ONE line on stderr, ``error: FILE: line N: ...`` (N is the
CSV line, header = line 1; the column is named where there is one), and exit code 2:
a file that is missing, a directory, empty, not UTF-8 text or not CSV; a header without
rows; a missing, unknown or repeated column; a cell that is not a number; a blank
parameter; a parameter outside the model's domain (not finite; Hr, a compliance or a
resistance <= 0; r_sys not in (0, 2/3)); an observation impossible in its unit (LVEF is a
fraction, not percent; see :data:`cvsim6.studies.ehr.PLAUSIBLE_RANGE`); an option below its
minimum (``--steps-per-cycle`` < :data:`cvsim6.model.solver.MIN_STEPS_PER_CYCLE`). Blank lines
are skipped; ``NA``, ``NaN``, ``none`` and ``null`` count as blank.

Unphysical values are flagged, not errors: a parameter set the equations accept but no
circulation has (a negative unstressed volume, a ventricle's systolic compliance not
below its diastolic one) is simulated and flagged in ``status`` (status 8 of
:data:`cvsim6.model.solver.STATUS_REASONS`), as is a row whose solution leaves the
physiological range; the other rows are unaffected and the exit code is 0. ``invert``
flags its decoded parameter sets the same way, per draw (``draw_status``, and
``outside_domain`` for sets the simulator cannot take).

``invert`` inverts every patient it can: one that cannot be inverted (all outputs blank,
say) keeps one row with the reason in ``status``; an observed output far outside the
range the networks were trained on is inverted but named in ``outside_training``. Each
such case prints a ``warning: FILE: line N ...`` line on stderr. Exit code 1 when a
patient was not inverted (the others are written), else 0.

Start-up: ``--help`` imports neither torch nor numba (the commands import what they use);
the solver's kernel compiles on its first use, with a message, and is cached on disk.
"""
from __future__ import annotations

import argparse
import csv
import logging
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6 import __version__
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES, PHYSIOLOGICAL_RANGE

# The commands import the solver (numba) and the networks (torch) when they run, so that
# ``cvsim6 --help`` starts at once; this module is no workflow rule's, so these late imports
# hide no rerun trigger.

#: The workflow command that converts only the paper's published EHR networks, and where
#: they land: the quickest way to models for ``cvsim6 invert``.
PUBLISHED_EHR_COMMAND = "snakemake --cores 1 convert_published_ehr"
PUBLISHED_EHR_MODELS = "results/published/models/ehr"
#: Cell texts read as blank (case-insensitive, after stripping spaces).
BLANK = frozenset({"", "na", "n/a", "nan", "none", "null"})


class InputError(Exception):
    """Bad input or option: the command prints ``error: <message>`` and exits with 2."""


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _read_csv(path: str) -> tuple[pd.DataFrame, np.ndarray]:
    """The CSV at ``path`` as strings (blank cells NaN) and each row's line number in the
    file (header = line 1, or the first line that is not blank: ``attrs["header_line"]``).
    Raises :class:`InputError` saying why it cannot be read."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: no such file")
    if p.is_dir():
        raise InputError(f"{path}: is a directory, not a CSV file")
    records, lines, prev = [], [], 0
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            for rec in reader:
                start, prev = prev + 1, reader.line_num
                if len(rec) > 1 or (rec and rec[0].strip()):  # pandas' rule: blank lines are skipped
                    records.append(rec)
                    lines.append(start)
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a CSV file (not UTF-8 text)") from None
    except csv.Error as exc:
        raise InputError(f"{path}: not a CSV file ({_one_line(exc)}, line {prev + 1})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or _one_line(exc)}") from None
    if not records:
        raise InputError(f"{path}: the file is empty (no header, no rows)")
    header = [h.strip() for h in records[0]]
    if len(header) == 1 and (";" in header[0] or "\t" in header[0]):
        sep = "';'" if ";" in header[0] else "tabs"
        raise InputError(f"{path}: line {lines[0]}: the header is a single column: fields separated by {sep}? "
                         "cvsim6 reads comma-separated values")
    seen: dict[str, int] = {}
    for h in header:
        if h and h in seen:
            raise InputError(f"{path}: line {lines[0]}: column {h} appears twice in the header")
        seen[h] = 1
    for rec, line in zip(records[1:], lines[1:]):
        if len(rec) > len(header):
            raise InputError(f"{path}: line {line}: {len(rec)} values but the header (line {lines[0]}) "
                             f"has {len(header)} columns")
    rows = [rec + [""] * (len(header) - len(rec)) for rec in records[1:]]
    df = pd.DataFrame(rows, columns=header, dtype=object)
    df = df.map(lambda c: np.nan if c.strip().lower() in BLANK else c.strip())
    df.attrs["header_line"] = lines[0]
    return df, np.array(lines[1:], dtype=int)


def _numbers(df: pd.DataFrame, columns: list[str], path: str, lines: np.ndarray) -> pd.DataFrame:
    """``df[columns]`` as floats (blank = NaN); a cell that is not a number raises
    :class:`InputError` naming its line and column."""
    out = {}
    for c in columns:
        col = df[c]
        try:
            out[c] = np.asarray(col.fillna("nan").to_list(), dtype=float)
        except ValueError:
            for i, cell in enumerate(col):
                try:
                    float("nan" if pd.isna(cell) else cell)
                except ValueError:
                    raise InputError(f"{path}: line {lines[i]}, column {c}: {cell!r} is not a number") from None
            raise  # pragma: no cover - a float() that numpy rejected
    return pd.DataFrame(out, index=df.index)


def _check_output(path: str, inputs: list[str]) -> Path:
    """The output path, after checking that it can be written and overwrites no input."""
    out = Path(path)
    if out.is_dir():
        raise InputError(f"{path}: the output is a directory")
    if any(out.resolve() == Path(i).resolve() for i in inputs):
        raise InputError(f"{path}: the output would overwrite the input")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{path}: cannot create its folder: {exc.strerror or _one_line(exc)}") from None
    if not os.access(out.parent, os.W_OK) or (out.exists() and not os.access(out, os.W_OK)):
        raise InputError(f"{path}: not writable")
    return out


def _write_csv(df: pd.DataFrame, out: Path, float_format: str) -> None:
    try:
        df.to_csv(out, index=False, float_format=float_format)
    except OSError as exc:
        raise InputError(f"{out}: cannot write: {exc.strerror or _one_line(exc)}") from None


def _lines(lines, limit: int = 5) -> str:
    lines = [str(n) for n in lines]
    return ", ".join(lines[:limit]) + (f" and {len(lines) - limit} more" if len(lines) > limit else "")


def _simulate(args: argparse.Namespace) -> int:
    from cvsim6.model import solver
    from cvsim6.model.equations import ParameterError

    if args.steps_per_cycle < solver.MIN_STEPS_PER_CYCLE:
        raise InputError(f"--steps-per-cycle {args.steps_per_cycle} is below the solver's minimum of "
                         f"{solver.MIN_STEPS_PER_CYCLE}")
    path = args.params
    df, lines = _read_csv(path)
    head = f"{path}: line {df.attrs['header_line']}"
    if not any(n in df.columns for n in PARAMETER_NAMES):
        raise InputError(f"{head}: no parameter column in the header; expected the 23 names "
                         f"{', '.join(PARAMETER_NAMES)}")
    missing = [n for n in PARAMETER_NAMES if n not in df.columns]
    if missing:
        raise InputError(f"{head}: missing parameter column(s) {', '.join(missing)}")
    if len(df) == 0:
        raise InputError(f"{path}: no rows (the file has a header only)")
    bad = solver.first_invalid_row(df[list(PARAMETER_NAMES)])
    if bad is not None:
        row, col, why = bad
        raise InputError(f"{path}: line {lines[row]}" + (f", column {col}" if col else "") + f": {why}")
    params = _numbers(df, list(PARAMETER_NAMES), path, lines)
    out = _check_output(args.output, [path])
    if args.method == "batch" and not solver.kernel_is_cached():
        print("compiling the solver on first use (about a minute; cached for later runs) ...", file=sys.stderr)
    try:
        result = solver.simulate(params, method=args.method, steps_per_cycle=args.steps_per_cycle,
                                 progress=args.progress)
    except ParameterError as exc:  # pragma: no cover - first_invalid_row found every such row
        raise InputError(f"{path}: {exc}") from None
    _warn_unphysiological(result, path, lines)
    extra = [c for c in df.columns if c not in PARAMETER_NAMES and c not in result.columns]
    result = pd.concat([df[extra].reset_index(drop=True), result.reset_index(drop=True)], axis=1)
    _write_csv(result, out, "%.10g")
    flagged = result["status"] != "ok"
    msg = f"simulated {len(result)} parameter set(s) -> {out}"
    if flagged.any():
        msg += (f" ({int(flagged.sum())} flagged, see the status column: "
                f"line {_lines(lines[flagged.to_numpy()])})")
    print(msg, file=sys.stderr)
    return 0


def _warn_unphysiological(result: pd.DataFrame, path: str, lines: np.ndarray, limit: int = 20) -> None:
    """A ``warning:`` line on stderr per simulated output outside its physiological range, in row
    order (at most ``limit``, then one line counting the rest per output, most frequent first);
    rows flagged in ``status`` are left to that column."""
    found = []
    ok = (result["status"] == "ok").to_numpy()
    for name, (low, high) in PHYSIOLOGICAL_RANGE.items():
        values = result[name].to_numpy(float)
        for i in np.flatnonzero(ok & ((values < low) | (values > high))):
            found.append((i, name, f"{name} = {values[i]:.4g} outside its physiological range {low:g} to {high:g}"))
    found.sort(key=lambda item: item[0])
    for i, _, message in found[:limit]:
        print(f"warning: {path}: line {lines[i]}: {message} (parameters in clinical units?)", file=sys.stderr)
    rest = pd.Series([name for _, name, _ in found[limit:]], dtype=object).value_counts(sort=False)
    if len(rest):
        rest = rest.sort_values(ascending=False, kind="stable")
        per_output = ", ".join(f"{name} {count:,}" for name, count in rest.items())
        print(f"warning: {path}: {len(found) - limit:,} more output(s) outside their physiological range "
              f"({per_output})", file=sys.stderr)


def _invert(args: argparse.Namespace) -> int:
    from cvsim6.data.datasets import load_split
    from cvsim6.nets import DEFAULT_CORRECTOR_STEPS
    from cvsim6.studies.ehr import invert_observations, unit_message, unit_problems

    if args.corrector_steps is None:
        args.corrector_steps = DEFAULT_CORRECTOR_STEPS
    for opt, value, low in (("--samples", args.samples, 1), ("--flow-samples", args.flow_samples, 1),
                            ("--reference-size", args.reference_size, 1),
                            ("--corrector-steps", args.corrector_steps, 0)):
        if value < low:
            raise InputError(f"{opt} {value} is below its minimum of {low}")
    path = args.observations
    df, lines = _read_csv(path)
    head = f"{path}: line {df.attrs['header_line']}"
    unknown = [c for c in df.columns if c not in OUTPUT_NAMES and c != "patient"]
    if unknown:
        raise InputError(f"{head}: unknown column(s) {', '.join(map(repr, unknown))}; expected 'patient' and any "
                         f"of the 16 outputs {', '.join(OUTPUT_NAMES)}")
    names = [n for n in OUTPUT_NAMES if n in df.columns]
    if not names:
        raise InputError(f"{head}: no output column in the header; expected any of {', '.join(OUTPUT_NAMES)}")
    if len(df) == 0:
        raise InputError(f"{path}: no patients (the file has a header only)")
    obs = _numbers(df, names, path, lines)
    if "patient" in df.columns:
        ids = df["patient"]
        first_seen: dict[str, int] = {}
        for i, pid in enumerate(ids):
            if pd.isna(pid):
                raise InputError(f"{path}: line {lines[i]}, column patient: blank patient name")
            if pid in first_seen:
                raise InputError(f"{path}: line {lines[i]}, column patient: patient {pid!r} appears twice "
                                 f"(also line {first_seen[pid]})")
            first_seen[pid] = lines[i]
        obs.index = pd.Index(ids.to_list(), name="patient")
    problems = unit_problems(obs)
    if problems:
        i = problems[0][0]
        raise InputError(f"{path}: {unit_message(problems, f'line {lines[i]}' + _who(obs, i, df))}")
    line_of = dict(zip(obs.index, lines))
    models = Path(args.models)
    tag = f"{args.noise_level:g}"
    files = {"emulator": models / "emulator.pt", "flow": models / f"flow_delta{tag}.pt",
             "encoder_decoder": models / f"encoder_decoder_delta{tag}.pt"}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise InputError(f"model file(s) not found: {', '.join(missing)}; the paper's networks in a few "
                         f"seconds: `{PUBLISHED_EHR_COMMAND}` (then --models {PUBLISHED_EHR_MODELS}); "
                         f"or train them with the workflow, or pass --models and --noise-level")
    out = _check_output(args.output, [path])

    def warn(pid, message: str) -> None:
        i = obs.index.get_loc(pid)
        print(f"warning: {path}: line {line_of[pid]}{_who(obs, i, df)}: {message}", file=sys.stderr)

    nets = {k: _load_model(f) for k, f in files.items()}
    ref = None
    if args.reference:
        if not Path(args.reference).is_file():
            raise InputError(f"--reference {args.reference}: no such file")
        try:
            ref = load_split(args.reference)[1]
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"--reference {args.reference}: not a split of simulated data "
                             f"({_one_line(exc)})") from None
    try:
        result = invert_observations(obs, nets["flow"], nets["encoder_decoder"], nets["emulator"],
                                     n_latent=args.samples, n_flow_samples=args.flow_samples, seed=args.seed,
                                     reference_outputs=ref, n_reference=args.reference_size, progress=args.progress,
                                     corrector_steps=args.corrector_steps, on_warning=warn)
    except ValueError as exc:  # pragma: no cover - the checks above catch what it rejects
        raise InputError(f"{path}: {_one_line(exc)}") from None
    _write_csv(result.rename(columns={"id": "patient"}), out, "%.8g")
    status = result.groupby("id", sort=False)["status"].first()
    failed = status[status != "ok"]
    msg = f"inverted {len(status) - len(failed)} of {len(status)} patient(s) x {args.samples} samples -> {out}"
    if len(failed):
        msg += f"; not inverted: line {_lines([line_of[p] for p in failed.index])} (see the status column)"
    print(msg, file=sys.stderr)
    return 1 if len(failed) else 0


def _load_model(path: Path):
    """A saved network; a file that is not one raises :class:`InputError`."""
    import pickle

    from cvsim6.nets import load_model

    try:
        return load_model(path)
    except (OSError, RuntimeError, ValueError, KeyError, EOFError, pickle.UnpicklingError) as exc:
        raise InputError(f"{path}: not a cvsim6 model file ({type(exc).__name__}: {_one_line(exc)[:200]})") from None


def _who(obs: pd.DataFrame, i: int, df: pd.DataFrame) -> str:
    return f" (patient {obs.index[i]})" if "patient" in df.columns else ""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cvsim6", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="simulate parameter sets to the 16 clinical outputs")
    sim.add_argument("params", help="CSV with the 23 parameter names as header (clinical units)")
    sim.add_argument("-o", "--output", required=True, help="output CSV: 16 outputs + status")
    sim.add_argument("--method", choices=("batch", "reference"), default="batch",
                     help="batch: fast fixed-step SDIRK (default); reference: scipy Radau, slow")
    sim.add_argument("--steps-per-cycle", type=int, default=600,
                     help="time steps per cardiac cycle of the batch solver (default 600, at least 20)")
    sim.add_argument("--progress", action="store_true", help="show a progress bar")
    sim.set_defaults(func=_simulate)
    inv = sub.add_parser("invert", help="infer parameter sets of patients from (partial) observations")
    inv.add_argument("observations", help="CSV: any of the 16 output names as columns, one patient per row")
    inv.add_argument("-o", "--output", required=True, help="output CSV: samples, emulated outputs, OOD")
    inv.add_argument("--models", default="results/models/ehr",
                     help="folder with emulator.pt, flow_delta<d>.pt, encoder_decoder_delta<d>.pt")
    inv.add_argument("--noise-level", type=float, default=0.5, help="training-noise level delta (default 0.5)")
    inv.add_argument("--samples", type=int, default=100, help="latent draws per patient (default 100)")
    inv.add_argument("--flow-samples", type=int, default=200_000,
                     help="flow samples ranked to complete missing outputs (paper: 5.1 million)")
    inv.add_argument("--reference", help="Parquet split of simulated data for the OOD percentile and the "
                                          "training range (default: samples of the flow)")
    inv.add_argument("--reference-size", type=int, default=200,
                     help="reference rows for the OOD percentile (default 200: resolution 0.5 percentage points; "
                          "the time grows with it, once per distinct set of missing outputs)")
    inv.add_argument("--corrector-steps", type=int, default=None,
                     help="predictor-corrector rounds when decoding (default: the library's, as the "
                          "paper's code; 0 = off)")
    inv.add_argument("--seed", type=int, default=0,
                     help="seed of every random draw: completions, latent draws, OOD reference")
    inv.add_argument("--progress", action="store_true", help="show a progress bar")
    inv.set_defaults(func=_invert)
    return parser


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except InputError as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
