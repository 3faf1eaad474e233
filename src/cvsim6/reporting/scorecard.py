"""The reproduction scorecard: every headline number of the paper beside ours, on one page.

A *source* is where the networks come from: ``trained`` by this workflow or
``published`` (the paper's own networks run through this project's code). Each source's
headlines are read from the workflow outputs it produced (:mod:`cvsim6.reporting.headline_files`); the
scorecard lists each headline with the paper's value, each source's value and its ratio
to the paper, and where it comes from in the paper and in ``results/``.

Ratios are ``ours / paper``. For a row that compares a whole table (one value per output)
the value *is* a ratio: the geometric mean over the outputs of ``ours / paper``, so the
paper's entry is 1. A headline is "within x" when ``max(r, 1/r) <= x``.
"""
from __future__ import annotations

import io
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6 import paper_values
from cvsim6.registry import OUTPUT_NAMES
from cvsim6.reporting.headline_files import HEADLINE_FILES
from cvsim6.table_files import to_markdown

#: Outputs count in the e_k headlines when observed in more than this many patients.
MIN_PATIENTS_EXCLUSIVE = 10
#: Tolerances the summary line counts against (max(r, 1/r)).
TOLERANCES = (1.15, 1.5)


@dataclass(frozen=True)
class Headline:
    """One row: ``paper`` value, where the paper gives it, the file of ours, and whether the
    value is already a ratio to the paper (a whole table summarized)."""

    key: str
    label: str
    paper: float
    where: str
    file: str
    is_ratio: bool = False


def geomean_ratio(ours: np.ndarray, paper: np.ndarray) -> float:
    """Geometric mean over the entries of ours / paper (dimensionless), skipping entries that are
    not finite or not positive on either side; NaN when none is left."""
    ours, paper = np.asarray(ours, float), np.asarray(paper, float)
    ok = np.isfinite(ours) & np.isfinite(paper) & (ours > 0) & (paper > 0)
    if not ok.any():
        return math.nan
    return float(np.exp(np.mean(np.log(ours[ok] / paper[ok]))))


def _read_json(path: str) -> dict:
    return json.loads(Path(path).read_text())


def counted_outputs(counts: Mapping[str, int]) -> list[str]:
    """Outputs that count in the e_k headlines: observed in more than 10 patients (``counts``:
    patients per output name) and given by the paper, in registry order."""
    return [n for n in OUTPUT_NAMES
            if counts.get(n, 0) > MIN_PATIENTS_EXCLUSIVE and paper_values.EHR_EK[n][0] is not None]


def ek_outputs(ehr_errors: pd.DataFrame) -> list[str]:
    """Outputs of table 5 that count (:func:`counted_outputs` of its ``Counts`` column)."""
    return counted_outputs(ehr_errors.set_index("Output")["Counts"].astype(str).str.split("/").str[0].astype(int))


def best_delta(ehr_errors: pd.DataFrame, outputs: list[str]) -> list[float]:
    """Noise level delta of the lowest e_k of each of ``outputs`` (NaN where none is finite, or
    the table lacks a noise level of the paper's)."""
    t = ehr_errors.set_index("Output")
    cols = [f"delta={d:g}" for d in paper_values.EHR_DELTAS]
    if not set(cols) <= set(t.columns):
        return [math.nan] * len(outputs)
    best = []
    for n in outputs:
        ek = t.loc[n, cols].to_numpy(float)
        best.append(paper_values.EHR_DELTAS[int(np.nanargmin(ek))] if np.isfinite(ek).any() else math.nan)
    return best


def paper_best_delta(outputs: list[str]) -> list[float]:
    """The paper's noise level delta of the lowest e_k of each of ``outputs`` (table 5)."""
    return [paper_values.EHR_DELTAS[int(np.argmin(paper_values.EHR_EK[n]))] for n in outputs]


def best_delta_agreement(ehr_errors: pd.DataFrame, outputs: list[str]) -> int:
    """Number of ``outputs`` whose lowest e_k is at the same noise level as the paper's."""
    return sum(ours == paper for ours, paper in zip(best_delta(ehr_errors, outputs), paper_best_delta(outputs)))


def headline_values(files: dict[str, str]) -> tuple[dict[str, float], list[Headline]]:
    """``({key: value}, headlines)`` of one source, read from its workflow outputs."""
    values: dict[str, float] = {}
    rows: list[Headline] = []

    def add(key, label, paper, where, file, value, is_ratio=False):
        rows.append(Headline(key, label, float(paper), where, file, is_ratio))
        values[key] = float(value)

    for key, name, where in (("structural_emulator", "Structural emulator", "appendix C table"),
                             ("structural_inversion", "Amortized inversion", "table 3")):
        table = pd.read_csv(files[key])
        for stat in ("Mean", "Max"):
            add(f"{key}_{stat.lower()}",
                f"{name}, {stat.lower()} abs. error: geometric mean of ours/paper over 16 outputs", 1.0, where,
                files[key], geomean_ratio(table[f"{stat} (ours)"], table[f"{stat} (paper)"]), is_ratio=True)
    h = paper_values.STRUCTURAL_HEADLINES
    manifold = _read_json(files["manifold"])
    add("manifold_l2", "Manifold reconstruction of y*: max relative l2 error (%)", 100 * h["max_rel_error_manifold"],
        "section 3.3.1, fig. 8", files["manifold"], 100 * manifold["max_rel_l2_error"])
    spread = manifold.get("max_rel_l2_error_resampled")
    if spread:  # beyond the paper: the same max, for other draws than the first 100
        add("manifold_l2_resampled", f"Manifold reconstruction: the same max over {spread['subset']} draws, median over "
            f"{spread['resamples']:,} random sets of {spread['subset']} of {spread['n_simulated']:,} draws (%)",
            100 * h["max_rel_error_manifold"], "section 3.3.1, fig. 8", files["manifold"], 100 * spread["q50"])
    svd = _read_json(files["svd"])
    add("svd_modes", "SVD of the manifold: modes for 99% of the energy", h["modes_99"], "section 3.3.2, fig. 10",
        files["svd"], svd["modes"])
    add("svd_energy", "SVD of the manifold: energy held by those modes (%)", 100 * h["energy_at_modes"],
        "section 3.3.2, fig. 10", files["svd"], 100 * svd["energy"])
    add("missing_l2", "Missing data: max relative l2 error on the observed entries (%)",
        100 * h["max_rel_error_missing"], "section 3.3.3, fig. 11", files["missing"],
        100 * _read_json(files["missing"])["max_rel_l2_error_observed"])
    add("ehr_emulator_l2", "EHR emulator: max relative l2 error on the validation sets (%)",
        100 * paper_values.EHR_EMULATOR_MAX_REL_L2, "section 3.4, fig. 12", files["ehr_emulator"],
        100 * _read_json(files["ehr_emulator"])["max"])
    ek = pd.read_csv(files["ehr_errors"])
    outputs = ek_outputs(ek)
    t = ek.set_index("Output")
    for i, d in enumerate(paper_values.EHR_DELTAS):
        col = f"delta={d:g}"
        if col not in t.columns:
            continue
        add(f"ek_{d:g}", f"EHR e_k at delta = {d:g}: geometric mean of ours/paper over the {len(outputs)} outputs "
            f"observed in > {MIN_PATIENTS_EXCLUSIVE} patients", 1.0, "table 5", files["ehr_errors"],
            geomean_ratio(t.loc[outputs, col], [paper_values.EHR_EK[n][i] for n in outputs]), is_ratio=True)
    add("ek_best_delta", f"EHR: outputs whose lowest e_k is at the paper's delta (of {len(outputs)})",
        len(outputs), "table 5", files["ehr_errors"], best_delta_agreement(ek, outputs))
    st = pd.read_csv(files["stiffness"])
    for instant in ("SR max", "SR min"):
        rows_i = st[st["Instant"] == instant].set_index("Quantity")
        for j in range(1, 5):
            q = f"lambda_{j} (1/s)"
            add(f"lambda_{j}_{instant.split()[1]}", f"Stiffness: lambda_{j} of A(t) at {instant} (1/s)",
                paper_values.STIFFNESS_EXTREMES[instant]["lambdas"][j - 1], "section 3.1, figs. 4-5",
                files["stiffness"], float(rows_i.loc[q, "This work"]))
    return values, rows


def ratio_to_paper(value: float, h: Headline) -> float:
    """``value / paper`` of headline ``h`` (``value`` itself for a row that is a ratio already)."""
    if h.is_ratio:
        return value
    return value / h.paper if h.paper != 0 else math.nan


def fmt(x: float) -> str:
    """A value as printed in the scorecard: integers whole, else three significant digits."""
    if not math.isfinite(x):
        return ""
    if float(x).is_integer() and abs(x) < 1e6:
        return str(int(x))
    return f"{x:.3g}" if abs(x) < 1e4 else f"{x:.4g}"


def scorecard_table(sources: dict[str, dict[str, str]]) -> pd.DataFrame:
    """One row per headline: the paper's value, and per source its value and ratio to the paper."""
    table, order = {}, []
    for source, files in sources.items():
        values, rows = headline_values(files)
        for h in rows:
            if h.key not in table:
                table[h.key] = {"Headline": h.label, "Paper": h.paper, "Paper section": h.where}
                order.append(h.key)
            r = table[h.key]
            r[f"{source}"] = values[h.key]
            r[f"{source} / paper"] = ratio_to_paper(values[h.key], h)
            r[f"{source} file"] = h.file
    return pd.DataFrame([table[k] for k in order])


def formatted(table: pd.DataFrame, text_columns: tuple[str, ...] = ()) -> pd.DataFrame:
    """A copy of ``table`` with every column but ``text_columns`` written as :func:`fmt` prints it."""
    shown = table.copy()
    for c in shown.columns:
        if c not in text_columns:
            shown[c] = [fmt(v) for v in shown[c]]
    return shown


def within(ratios: pd.Series, tol: float) -> tuple[int, int]:
    """(rows with max(r, 1/r) <= tol, rows with a ratio)."""
    r = ratios.astype(float)
    r = r[np.isfinite(r) & (r > 0)]
    return int((np.maximum(r, 1 / r) <= tol).sum()), len(r)


def ek_per_output(sources: dict[str, dict[str, str]]) -> pd.DataFrame:
    """e_k per output (rows) and delta: the paper's and each source's, outputs of table 5 only."""
    ours = {s: pd.read_csv(f["ehr_errors"]).set_index("Output") for s, f in sources.items()}
    first = next(iter(ours.values())).reset_index()
    outputs = ek_outputs(first)
    rows = []
    for n in outputs:
        row = {"Output": n}
        for i, d in enumerate(paper_values.EHR_DELTAS):
            row[f"paper {d:g}"] = paper_values.EHR_EK[n][i]
            for s, t in ours.items():
                col = f"delta={d:g}"
                row[f"{s} {d:g}"] = float(t.loc[n, col]) if col in t.columns else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def read_spread(text: str | None) -> pd.DataFrame | None:
    """The spread over seeds from the text of ``seeds.csv`` (None for None or empty text)."""
    if not text:
        return None
    return pd.read_csv(io.StringIO(text))


def add_seed_spread(table: pd.DataFrame, spread: pd.DataFrame, source: str) -> pd.DataFrame:
    """``table`` with the ratios to the paper of the minimum, median and maximum over seeds of
    ``source``'s networks (rows of ``seeds.csv``, matched by headline), after its own ratio."""
    by_label = spread.set_index("Headline")
    out = table.copy()
    at = list(out.columns).index(f"{source} / paper") + 1
    for i, stat in enumerate(("min", "median", "max")):
        col = f"{source} {stat} over seeds / paper"
        out.insert(at + i, col, [by_label[f"{stat} / paper"].get(h, math.nan) for h in out["Headline"]])
    return out


def write_scorecard(csv: str, md: str, source: str, other_sources: dict[str, dict[str, str]],
                    seed_spread: str | None = None, **files: str) -> None:
    """Workflow step: the scorecard of ``source`` (its headline files as keyword arguments,
    :data:`HEADLINE_FILES`) and of each other source whose files all exist, side by side.
    ``seed_spread``, the text of the spread over seeds (``seeds.csv`` of
    :mod:`cvsim6.reporting.seed_scorecard`), adds the trained networks' minimum, median and
    maximum ratios over the seeds beside the default seed's."""
    missing = [k for k in HEADLINE_FILES if k not in files]
    if missing:
        raise ValueError(f"headline files missing for {source!r}: {missing}")
    sources = {source: {k: files[k] for k in HEADLINE_FILES}}
    skipped = []
    for name, other in sorted(other_sources.items()):
        if all(Path(other[k]).is_file() for k in HEADLINE_FILES):
            sources[name] = other
        else:
            skipped.append(name)
    sources = dict(sorted(sources.items(), key=lambda kv: kv[0] != "trained"))  # trained first
    table = scorecard_table(sources)
    spread = read_spread(seed_spread) if source == "trained" else None
    if spread is not None:
        table = add_seed_spread(table, spread, source)
    Path(csv).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(csv, index=False)
    lines = ["# Reproduction scorecard", "",
             "How close this reproduction comes to the paper's headline numbers, "
             f"for the networks {' and '.join(repr(s) for s in sources)}: "
             "`trained` by this workflow, `published` = the paper's own networks run through this "
             "project's code (they isolate our inference from our training). Ratios are ours / paper; "
             "rows marked *ours/paper* hold that ratio already (geometric mean over the outputs of a table, "
             "the paper's entry is 1).", ""]
    for s in sources:
        counts = ["{} of {} within {:g}x".format(*within(table[f"{s} / paper"], tol), tol) for tol in TOLERANCES]
        lines.append(f"- **{s}**: " + ", ".join(counts) + ".")
    if spread is not None:
        seeds = [c.split()[1] for c in spread.columns if c.startswith("seed ")]
        lines.append(f"- **{source} over seeds** {', '.join(seeds)} (`snakemake seeds`, details in "
                     "`results/report/seeds.md`): the minimum, median and maximum of each ratio.")
    if skipped:
        lines.append(f"- not built yet, so not shown: {', '.join(skipped)} "
                     "(run the workflow with that source, then rebuild this file).")
    lines.append("")
    spread_cols = [c for c in table.columns if " over seeds / paper" in c]
    shown = formatted(table[["Headline", "Paper"] + [c for s in sources for c in (s, f"{s} / paper")]
                            + spread_cols + ["Paper section"]], ("Headline", "Paper section"))
    lines.append(to_markdown(shown))
    lines += ["", "Files: " + "; ".join(f"`{s}`: `{Path(f['ehr_errors']).parent.parent}/`" for s, f in sources.items()),
              ""]
    ek = ek_per_output(sources)
    ek_shown = formatted(ek, ("Output",))
    lines.append(to_markdown(ek_shown, caption="EHR e_k per output and noise level delta (table 5), "
                                               "outputs observed in more than 10 patients"))
    Path(md).write_text("\n".join(lines), encoding="utf-8")
