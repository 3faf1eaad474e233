"""Inverting real patients (paper section 3.4) and new ones (the ``cvsim6 invert`` CLI).

Per observation (16 outputs, NaN = missing): Algorithm 1 keeps the most likely
completion under NN_f, N_w latent draws are decoded by NN_d into parameter sets, and
the noise-free emulator NN_e maps them back to outputs. Each observation also gets
an out-of-distribution percentile (:mod:`cvsim6.inference.inversion`).

The error of output k at noise level delta is (paper eq. 9)
``e_k = mean over patients with y_k observed of mean_i |y_k - Y_ik|``.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.inference import inversion
from cvsim6 import paper_values
from cvsim6.data.datasets import load_split
from cvsim6.model.equations import outside_domain
from cvsim6.nets import DEFAULT_CORRECTOR_STEPS, load_model
from cvsim6.registry import OUTPUT_BY_NAME, OUTPUT_INDEX, OUTPUT_NAMES, OUTPUTS, PARAMETER_NAMES
from cvsim6.model.solver import STATUS_OUTSIDE_DOMAIN, STATUS_REASONS, STATUS_UNPHYSICAL, unphysical
from cvsim6.table_files import write_table

log = logging.getLogger(__name__)

#: Prefix of the emulated-output columns (Hr is both a parameter and an output);
#: :mod:`cvsim6.reporting.ehr_figures` reads them by the same prefix.
PRED = "pred_"


#: Values of each output that are possible at all, in its registry unit: ``(low, high)``
#: (inclusive). A value outside is taken for a unit mistake and rejected before anything
#: is computed. PVR's unit cannot be told by its value (a tiny transpulmonary gradient
#: gives a few dyn·s/cm^5), so only its sign is checked.
PLAUSIBLE_RANGE = {
    "Hr": (10.0, 400.0), **{n: (-50.0, 400.0) for n in OUTPUT_NAMES if n.startswith("P_")},
    "V_l_sys": (2.0, 1000.0), "V_l_dia": (2.0, 1000.0), "LVEF": (0.0, 1.0), "CO": (0.1, 50.0),
    "SVR": (50.0, 10_000.0), "PVR": (0.0, 3000.0),
}
#: The likely mistake when a value falls in ``(low, high]``: ``[(low, high, hint), ...]``.
UNIT_HINTS = {
    "Hr": [(0.0, 10.0, "beats per second? (Hr is in beats per minute)")],
    "LVEF": [(1.0, 100.0, "percent?")],
    "CO": [(50.0, 50_000.0, "mL/min?")],
    "SVR": [(0.0, 50.0, "Wood units (mmHg·min/L)? 1 WU = 80 dyn·s/cm^5")],
    "V_l_sys": [(0.0, 2.0, "litres?")], "V_l_dia": [(0.0, 2.0, "litres?")],
    **{n: [(400.0, 400.0 * 133.4, "Pa? (1 mmHg = 133.3 Pa)")] for n in OUTPUT_NAMES if n.startswith("P_")},
}
#: An observation is *outside the training range* beyond the range of the reference
#: outputs (simulated, or flow samples) widened by this fraction of its width on each side.
TRAINING_RANGE_MARGIN = 0.1
#: Flow samples drawn (from ``seed``) as the reference when no simulated outputs are given.
REFERENCE_FLOW_DRAWS = 2000


def unit_problem(name: str, value: float) -> tuple[str, str] | None:
    """``(expectation, hint)`` when ``value`` of output ``name`` is impossible in its unit
    (e.g. ``("LVEF is a fraction (0-1)", "percent?")``), else None. NaN (missing) is fine."""
    if np.isnan(value):
        return None
    lo, hi = PLAUSIBLE_RANGE[name]
    if lo <= value <= hi:
        return None
    if name == "LVEF":
        expect = "LVEF is a fraction (0-1)"
    else:
        expect = f"{name} is in {OUTPUT_BY_NAME[name].unit} ({lo:g} to {hi:g})"
    hint = next((h for a, b, h in UNIT_HINTS.get(name, []) if a < value <= b), "")
    return expect, hint


def unit_problems(observations: pd.DataFrame) -> list[tuple[int, str, float, str, str]]:
    """Every cell of ``observations`` (numeric output columns) impossible in its unit:
    ``(row position, column, value, expectation, hint)``, row by row."""
    found = []
    cols = [c for c in OUTPUT_NAMES if c in observations.columns]
    values = observations[cols].to_numpy(float)
    for i, j in zip(*np.nonzero(~np.isnan(values))):
        p = unit_problem(cols[j], float(values[i, j]))
        if p is not None:
            found.append((int(i), cols[j], float(values[i, j]), *p))
    return sorted(found, key=lambda t: (t[0], OUTPUT_NAMES.index(t[1])))


def unit_message(problems: list, where: str) -> str:
    """One line for the first of ``problems`` (from :func:`unit_problems`), ``where`` naming
    its row, e.g. ``"LVEF is a fraction (0-1); got 55 in line 3: percent? (2 values of LVEF)"``."""
    _, name, value, expect, hint = problems[0]
    n = sum(1 for p in problems if p[1] == name)
    more = f" ({n} such values of {name})" if n > 1 else ""
    return f"{expect}; got {value:g} in {where}" + (f": {hint}" if hint else "") + more


def training_range(reference_outputs: np.ndarray, margin: float = TRAINING_RANGE_MARGIN):
    """Per output ``(low, high)``: the range of the finite reference rows widened by
    ``margin`` times its width on each side (registry units)."""
    ref = np.asarray(reference_outputs, float)
    ref = ref[np.isfinite(ref).all(axis=1)]
    if len(ref) == 0:
        raise ValueError("the reference outputs have no finite row")
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    pad = margin * (hi - lo)
    return lo - pad, hi + pad


def _report(pid, message: str) -> None:
    log.warning("patient %r: %s", pid, message)


def invert_observations(observations: pd.DataFrame, flow, encdec, emulator, n_latent: int = 100,
                        n_flow_samples: int = 200_000, seed: int = 0,
                        reference_outputs: np.ndarray | None = None, n_reference: int = 100,
                        reference_flow_samples: int = 4096, progress: bool = False,
                        corrector_steps: int = DEFAULT_CORRECTOR_STEPS,
                        on_warning: Callable[[object, str], None] | None = None) -> pd.DataFrame:
    """Invert each row of ``observations`` (any subset of the 16 output columns, NaN = missing).

    Returns a long table, one row per observation and latent draw: ``id`` (the
    observation's index), ``status`` (``"ok"``, or ``"not inverted: <reason>"`` with a
    single row and no parameters), ``draw``, the 23 parameters, ``draw_status`` and
    ``outside_domain`` of each decoded set (:data:`cvsim6.model.solver.STATUS_REASONS` 7 and 8:
    a set the simulator cannot take, or an unphysical one), the 16 emulated outputs
    (``pred_<name>``), the completion used (``completed_<name>``), its ``log_density``,
    ``ood_percentile`` (percentage of ``ood_reference_size`` reference outputs less likely
    than the observation; resolution 100/size %), and ``outside_training`` (the observed
    outputs beyond the training range, ``;``-separated: their inversion extrapolates).

    ``reference_outputs`` (N, 16): simulated outputs for the OOD percentile (``n_reference``
    rows drawn with ``seed``) and the training range (all rows); None draws
    :data:`REFERENCE_FLOW_DRAWS` flow samples with ``seed`` instead. Every observation is
    ranked against the same reference rows, and Algorithm 1 completes every observation from the
    same ``n_flow_samples`` flow samples (drawn once with ``seed``). A row that cannot be inverted does not stop
    the others; each problem is passed to ``on_warning(id, message)`` (default: logged).
    Raises ValueError before computing anything for an unknown column, a value that is
    not a number, or one impossible in its unit (:func:`unit_problem`).
    ``corrector_steps``: predictor-corrector rounds of :func:`cvsim6.inference.inversion.decode_latent`.
    """
    obs = checked_observations(observations, n_latent=n_latent, n_flow_samples=n_flow_samples,
                               n_reference=n_reference, reference_flow_samples=reference_flow_samples)
    reference = _Reference.build(flow, reference_outputs, n_reference, reference_flow_samples, seed)
    settings = dict(n_latent=int(n_latent), n_flow_samples=n_flow_samples, seed=seed, corrector_steps=corrector_steps,
                    warn=on_warning or _report)
    y_all = obs.to_numpy()
    seen = np.isfinite(y_all).any(axis=1)
    completed = dict(zip(np.flatnonzero(seen), inversion.complete_missing_shared(
        flow, y_all[seen], n_flow_samples, top_k=1, seed=seed, progress=progress)))
    it = obs.iterrows()
    if progress:
        from tqdm import tqdm

        it = tqdm(it, total=len(obs), unit="patient", desc="decode")
    rows = [_invert_row(pid, y.to_numpy(), k, completed.get(k), flow, encdec, emulator, reference, **settings)
            for k, (pid, y) in enumerate(it)]
    out = pd.concat(rows, ignore_index=True)[_COLUMNS]
    return out.astype({"draw": "Int64", "outside_domain": "boolean", "ood_reference_size": "Int64"})


def checked_observations(observations: pd.DataFrame, **counts: int) -> pd.DataFrame:
    """``observations`` as floats in the 16 registry columns (registry units, NaN = missing).

    Raises ValueError for an unknown column, no rows, a count in ``counts`` (name -> value)
    below 1, a value that is not a number, or one impossible in its unit (:func:`unit_problem`)."""
    unknown = [c for c in observations.columns if c not in OUTPUT_NAMES]
    if unknown:
        raise ValueError(f"unknown output column(s) {unknown}; expected any of {list(OUTPUT_NAMES)}")
    if len(observations) == 0:
        raise ValueError("no observations to invert (the table has no rows)")
    for name, value in counts.items():
        if int(value) < 1:
            raise ValueError(f"{name} = {value} must be >= 1")
    obs = observations.reindex(columns=list(OUTPUT_NAMES))
    num = obs.apply(pd.to_numeric, errors="coerce")
    text = obs.notna() & num.isna()
    if text.any().any():
        i, j = np.argwhere(text.to_numpy())[0]
        raise ValueError(f"observation {obs.index[i]!r}: {OUTPUT_NAMES[j]} = {obs.iat[i, j]!r} is not a number")
    obs = num.astype(float)
    bad = unit_problems(obs)
    if bad:
        raise ValueError(unit_message(bad, f"observation {obs.index[bad[0][0]]!r}"))
    return obs


class _Reference:
    """The reference outputs every observation is compared with: the training range
    (``low``, ``high`` per output, registry units), the rows ranked for the OOD percentile,
    and their Algorithm-1 scores per missing pattern (computed once, on first use)."""

    def __init__(self, low: np.ndarray, high: np.ndarray, rows: np.ndarray, flow_samples: int, seed: int):
        self.low, self.high, self.rows = low, high, rows
        self.flow_samples, self.seed = int(flow_samples), seed
        self._scores: dict[bytes, np.ndarray] = {}

    @classmethod
    def build(cls, flow, reference_outputs: np.ndarray | None, n_reference: int, flow_samples: int,
              seed: int) -> "_Reference":
        """From ``reference_outputs`` (N, 16), or :data:`REFERENCE_FLOW_DRAWS` flow samples
        drawn with ``seed`` when None; ``n_reference`` finite rows picked with ``seed``."""
        if reference_outputs is None:
            gen = inversion.seeded_torch_generator(np.random.SeedSequence([int(seed), 1]).generate_state(1)[0])
            ref = flow.sample_physical(REFERENCE_FLOW_DRAWS, generator=gen)
        else:
            ref = np.asarray(reference_outputs, float)
        ref = ref[np.isfinite(ref).all(axis=1)]
        lo, hi = training_range(ref)
        pick = np.random.default_rng(seed).choice(len(ref), size=min(int(n_reference), len(ref)), replace=False)
        return cls(lo, hi, ref[pick], flow_samples, seed)

    def outside(self, y: np.ndarray) -> list[str]:
        """Names of the observed entries of ``y`` (16,) beyond the training range."""
        return [n for j, n in enumerate(OUTPUT_NAMES)
                if np.isfinite(y[j]) and not self.low[j] <= y[j] <= self.high[j]]

    def scores(self, flow, missing: np.ndarray) -> np.ndarray:
        """Algorithm-1 log-densities of the reference rows with the ``missing`` entries hidden."""
        key = missing.tobytes()
        if key not in self._scores:
            self._scores[key] = inversion.reference_scores(flow, self.rows, missing, self.flow_samples,
                                                           seed=self.seed)
        return self._scores[key]


def _invert_row(pid, y: np.ndarray, k: int, completion: tuple | None, flow, encdec, emulator,
                reference: _Reference, n_latent: int, n_flow_samples: int, seed: int, corrector_steps: int,
                warn: Callable[[object, str], None]) -> pd.DataFrame:
    """The rows of :func:`invert_observations` for observation ``pid`` (``y`` (16,), the
    ``k``-th row: its latent draws are seeded from ``seed`` and ``k``), given its Algorithm-1
    ``completion`` (best completion (1, 16), its log-density (1,)); None when nothing is seen."""
    seen = np.isfinite(y)
    outside = reference.outside(y)
    for n in outside:
        j = OUTPUT_INDEX[n]
        unit = OUTPUT_BY_NAME[n].unit
        warn(pid, f"{n} = {y[j]:g} {unit} is far outside the training range "
                  f"[{reference.low[j]:.4g}, {reference.high[j]:.4g}] {unit}: its inversion extrapolates")
    if not seen.any():
        warn(pid, "not inverted: no output given")
        return _not_inverted(pid, "no output given", outside)
    best, lp = completion
    if not np.isfinite(lp[0]) or not np.isfinite(best).all():
        why = f"no finite completion under the flow among {n_flow_samples} samples"
        warn(pid, f"not inverted: {why}")
        return _not_inverted(pid, why, outside)
    v = inversion.decode_latent(encdec, best, n_latent, seed=seed + 104729 * k, corrector_steps=corrector_steps)[0]
    dom = outside_domain(v)
    if dom.any():
        warn(pid, f"{int(dom.sum())} of {n_latent} decoded parameter sets are outside the model's domain "
                  "(see outside_domain)")
    df = pd.DataFrame(v, columns=list(PARAMETER_NAMES))
    df.insert(0, "draw", np.arange(n_latent))
    df.insert(0, "status", "ok")
    df.insert(0, "id", pid)
    df["draw_status"] = np.where(dom, STATUS_REASONS[STATUS_OUTSIDE_DOMAIN],
                                 np.where(unphysical(v), STATUS_REASONS[STATUS_UNPHYSICAL], "ok"))
    df["outside_domain"] = dom
    yhat = np.asarray(emulator.predict(v))
    for j, name in enumerate(OUTPUT_NAMES):
        df[PRED + name] = yhat[:, j]
    for j, name in enumerate(OUTPUT_NAMES):
        df["completed_" + name] = best[0, j]
    scores = reference.scores(flow, ~seen)
    df["log_density"] = lp[0]
    df["ood_percentile"] = inversion.ood_percentile(lp[0], scores)
    df["ood_reference_size"] = int(np.isfinite(scores).sum())
    df["outside_training"] = ";".join(outside)
    return df


_COLUMNS = (["id", "status", "draw", *PARAMETER_NAMES, "draw_status", "outside_domain"]
            + [PRED + n for n in OUTPUT_NAMES] + ["completed_" + n for n in OUTPUT_NAMES]
            + ["log_density", "ood_percentile", "ood_reference_size", "outside_training"])


def _not_inverted(pid, reason: str, outside: list[str]) -> pd.DataFrame:
    """The single row of an observation that could not be inverted."""
    row = {c: np.nan for c in _COLUMNS}
    row.update(id=pid, status=f"not inverted: {reason}", draw=pd.NA, draw_status="", outside_domain=pd.NA,
               ood_reference_size=pd.NA, outside_training=";".join(outside))
    return pd.DataFrame([row], columns=_COLUMNS)


def invert_ehr_patients(patients: str, flow: str, encoder_decoder: str, emulator: str, reference: str,
                        predictions: str, noise_level: float, n_latent: int, n_flow_samples: int,
                        n_reference: int, reference_flow_samples: int, seed: int,
                        corrector_steps: int = DEFAULT_CORRECTOR_STEPS) -> None:
    """Workflow step: invert the selected EHR patients with the networks of one noise level
    (a patient that cannot be inverted is logged and kept with its reason in ``status``)."""
    obs = pd.read_csv(patients, index_col="patient")[list(OUTPUT_NAMES)]
    _, y_ref = load_split(reference)
    df = invert_observations(obs, load_model(flow), load_model(encoder_decoder), load_model(emulator),
                             n_latent=n_latent, n_flow_samples=n_flow_samples, seed=seed,
                             reference_outputs=y_ref, n_reference=n_reference,
                             reference_flow_samples=reference_flow_samples, progress=True,
                             corrector_steps=corrector_steps)
    df.insert(1, "noise_level", float(noise_level))
    Path(predictions).parent.mkdir(parents=True, exist_ok=True)
    df.to_parquet(predictions, index=False)
    per = df.groupby("id", sort=False)["status"].first()
    log.info("delta=%g: %d of %d patients inverted", noise_level, int((per == "ok").sum()), len(per))


def error_per_output(observations: pd.DataFrame, predictions: pd.DataFrame) -> pd.DataFrame:
    """e_k and counts per output: mean over observed patients of mean_i |y_k - Y_ik|
    (a patient without predictions, e.g. not inverted, is left out of e_k)."""
    rows = []
    for name in OUTPUT_NAMES:
        obs = observations[name].dropna()
        errs = []
        for pid, yk in obs.items():
            pred = predictions.loc[predictions["id"] == pid, PRED + name].to_numpy(float)
            pred = pred[np.isfinite(pred)]
            if len(pred):
                errs.append(np.abs(yk - pred).mean())
        rows.append({"output": name, "e_k": float(np.mean(errs)) if errs else np.nan,
                     "count": len(obs), "patients": len(observations)})
    return pd.DataFrame(rows).set_index("output")


def ehr_error_table(patients: str, predictions: list[str], csv: str, md: str) -> None:
    """The paper's table 5: e_k per output and noise level, counts, the paper's values beside."""
    obs = pd.read_csv(patients, index_col="patient")
    table = pd.DataFrame({"Output": list(OUTPUT_NAMES), "Unit": [o.unit for o in OUTPUTS]})
    deltas = []
    for path in predictions:
        pred = pd.read_parquet(path)
        d = float(pred["noise_level"].iloc[0])
        deltas.append(d)
        table[f"delta={d:g}"] = error_per_output(obs, pred)["e_k"].to_numpy()
    cols = [f"delta={d:g}" for d in deltas]
    table["Best (ours)"] = [cols[int(np.nanargmin(r))] if np.isfinite(r).any() else "" for r in table[cols].to_numpy()]
    for i, d in enumerate(paper_values.EHR_DELTAS):
        table[f"paper delta={d:g}"] = [paper_values.EHR_EK[n][i] for n in OUTPUT_NAMES]
    e = error_per_output(obs, pd.read_parquet(predictions[0]))
    table["Counts"] = [f"{c}/{n}" for c, n in zip(e["count"], e["patients"])]
    write_table(table, csv, md, caption="Reconstruction error e_k per output (N_w latent draws, emulated), "
                                        "EHR patients with more than 10 outputs; paper table 5 beside")


def ood_table(predictions: str, csv: str, md: str) -> None:
    """Per patient: log-density of the best completion, its OOD percentile, the reference
    size it was ranked in (resolution 100/size %), the outputs beyond the training range."""
    pred = pd.read_parquet(predictions)
    cols = [c for c in ("status", "log_density", "ood_percentile", "ood_reference_size", "outside_training")
            if c in pred.columns]
    per = pred.groupby("id")[cols].first().reset_index()
    per["flag (< 1st percentile)"] = per["ood_percentile"] < 1.0
    sizes = per["ood_reference_size"].dropna().unique() if "ood_reference_size" in per else []
    among = (f" {int(sizes[0]):,} simulated outputs (resolution {100 / sizes[0]:.2g} percentage points)"
             if len(sizes) == 1 else " simulated outputs")
    write_table(per.rename(columns={"id": "patient"}), csv, md,
                caption="Out-of-distribution score per patient: percentile of the flow log-density of "
                        f"its best completion among{among} with the same entries missing")
