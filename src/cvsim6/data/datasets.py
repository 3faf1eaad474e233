"""Training data of a study: prior sampling, sharded simulation, gathering and splits.

Datasets are Parquet files with the 23 parameter and 16 output columns in the
registry's clinical units; each column carries its unit and role ("parameter" or
"output") as Arrow field metadata. Reproducibility: every parameter set is drawn
from one stream seeded by (master seed, study) *before* sharding, and the solver's
rows are independent of their batch, so datasets are bit-identical whatever the
number of shards.
"""
from __future__ import annotations

import json
import logging
import time
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from cvsim6 import __version__
from cvsim6.data import priors
from cvsim6.model import solver
from cvsim6.registry import OUTPUT_BY_NAME, OUTPUT_NAMES, PARAMETER_BY_NAME, PARAMETER_NAMES

log = logging.getLogger(__name__)

SPLITS = ("train", "test", "validation")


class DataError(RuntimeError):
    """A dataset cannot be built as configured; the message says why."""


# ----------------------------------------------------------------------------- I/O
def _unit_metadata(column: str) -> dict[bytes, bytes]:
    if column in PARAMETER_BY_NAME:
        return {b"role": b"parameter", b"unit": PARAMETER_BY_NAME[column].unit.encode()}
    if column in OUTPUT_BY_NAME:
        return {b"role": b"output", b"unit": OUTPUT_BY_NAME[column].unit.encode()}
    return {}


def write_dataset(df: pd.DataFrame, path: str | Path) -> None:
    """Write ``df`` to Parquet with unit/role metadata on parameter and output columns."""
    table = pa.Table.from_pandas(df, preserve_index=False)
    fields = [f.with_metadata(_unit_metadata(f.name)) if _unit_metadata(f.name) else f for f in table.schema]
    table = table.cast(pa.schema(fields, metadata=table.schema.metadata))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def read_dataset(path: str | Path) -> pd.DataFrame:
    """Read a dataset written by :func:`write_dataset`."""
    return pq.read_table(path).to_pandas()


def dataset_units(path: str | Path) -> dict[str, str]:
    """Column -> unit, from the Parquet field metadata."""
    schema = pq.read_schema(path)
    return {f.name: f.metadata[b"unit"].decode() for f in schema if f.metadata and b"unit" in f.metadata}


def load_split(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (N, 23) and outputs (N, 16) of a split file, float64, registry order.

    Reads only those columns (``Hr``, a parameter and an output, is one column) and
    raises ``ValueError`` naming the first non-finite cell: a split holds simulated sets
    only, so such a value means a damaged file.
    """
    columns = list(dict.fromkeys(PARAMETER_NAMES + OUTPUT_NAMES))
    df = pq.read_table(path, columns=columns).to_pandas()
    bad = ~np.isfinite(df.to_numpy(np.float64))
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(f"{path}: non-finite value in row {row}, column {columns[col]!r}")
    return df[list(PARAMETER_NAMES)].to_numpy(np.float64), df[list(OUTPUT_NAMES)].to_numpy(np.float64)


# ----------------------------------------------------------------------------- steps
def study_seed(seed: int, study: str) -> np.random.SeedSequence:
    """The seed sequence of one study, derived from the master seed and its name."""
    return np.random.SeedSequence([int(seed), zlib.crc32(study.encode())])


def sample_prior(parameters: str, prior: dict, n_samples: int, seed: int, study: str,
                 shards: list[str] | None = None) -> None:
    """Draw ``n_samples`` parameter sets of ``study`` from its uniform prior to Parquet.

    Column ``sample`` numbers the rows 0..n-1 (the order the splits follow). All
    sets come from one stream; ``shards`` (paths) then receive contiguous blocks of
    rows, so the data do not depend on the number of shards.
    """
    lo, hi = priors.prior_bounds(prior)
    rng = np.random.default_rng(study_seed(seed, study))
    P = priors.sample_uniform(lo, hi, int(n_samples), rng)
    df = pd.DataFrame(P, columns=list(PARAMETER_NAMES))
    df.insert(0, "sample", np.arange(len(df), dtype=np.int64))
    write_dataset(df, parameters)
    shards = [shards] if isinstance(shards, str) else list(shards or [])
    for i, path in enumerate(shards):
        write_dataset(df.iloc[shard_rows(len(df), i, len(shards))].reset_index(drop=True), path)
    log.info("%s: %d parameter sets drawn (seed %d), %d shard(s)", study, len(df), seed, len(shards))


def parse_scatteritem(item: str) -> tuple[int, int]:
    """``'3-of-8'`` -> (2, 8): zero-based shard index and shard count."""
    try:
        i, n = item.split("-of-")
        i, n = int(i), int(n)
    except ValueError as exc:
        raise ValueError(f"shard {item!r} is not of the form 'i-of-n'") from exc
    if not 1 <= i <= n:
        raise ValueError(f"shard {item!r}: index outside 1..{n}")
    return i - 1, n


def shard_rows(n_rows: int, index: int, n_shards: int) -> slice:
    """Contiguous rows of shard ``index`` of ``n_shards`` (sizes differ by at most 1)."""
    bounds = np.linspace(0, n_rows, n_shards + 1).round().astype(int)
    return slice(int(bounds[index]), int(bounds[index + 1]))


def simulate_shard(parameters: str, output: str, simulator: dict, shard: str = "1-of-1",
                   chunk_size: int = 1000) -> None:
    """Simulate the parameter sets of one shard file (``shard = 'i-of-n'``, for the log)
    with ``simulator['method']``: 'batch' (default) or 'reference' (slow; for checks).

    Writes the shard's rows with parameters, the 16 outputs and ``status``; logs
    progress and the rate (sets/s).
    """
    parse_scatteritem(shard)
    part = read_dataset(parameters)
    P = part[list(PARAMETER_NAMES)].to_numpy(float)
    log.info("shard %s: %d parameter sets", shard, len(P))
    t0 = time.perf_counter()
    out = np.empty((len(P), len(OUTPUT_NAMES)))
    status = np.empty(len(P), dtype=np.int64)
    from tqdm import tqdm

    with tqdm(total=len(P), unit="set", desc=f"shard {shard}", mininterval=5.0) as bar:
        for s in range(0, len(P), chunk_size):
            sl = slice(s, min(len(P), s + chunk_size))
            if simulator.get("method", "batch") == "reference":
                out[sl], status[sl] = solver.simulate_reference(
                    P[sl], n_cycles=simulator["n_cycles"], window_cycles=simulator["window_cycles"])
            else:
                out[sl], status[sl] = solver.simulate_batch(
                    P[sl], steps_per_cycle=simulator["steps_per_cycle"], n_cycles=simulator["n_cycles"],
                    window_cycles=simulator["window_cycles"])
            bar.update(sl.stop - sl.start)
    dt = time.perf_counter() - t0
    log.info("shard %s: %d sets in %.2f s (%.0f sets/s), %d flagged",
             shard, len(P), dt, len(P) / max(dt, 1e-9), int((status != 0).sum()))
    df = part.copy()
    for j, name in enumerate(OUTPUT_NAMES):
        df[name] = out[:, j]
    df["status"] = [solver.STATUS_REASONS[int(c)] for c in status]
    write_dataset(df, output)


def split_sizes(n_rows: int, validation: int, train_fraction: float) -> dict[str, int]:
    """Sizes of the three splits: the last ``validation`` rows, then ``train_fraction``
    of the rest (rounded down) for training and the remainder for testing."""
    if validation >= n_rows:
        raise DataError(f"validation = {validation} rows but only {n_rows} usable rows")
    n_train = int(np.floor(train_fraction * (n_rows - validation)))
    return {"train": n_train, "test": n_rows - validation - n_train, "validation": validation}


def gather_study(
    shards: list[str],
    train: str,
    test: str,
    validation: str,
    failures: str,
    manifest: str,
    study: str,
    split: dict,
    max_failure_fraction: float,
    prior: dict,
    seed: int,
    simulator: dict,
) -> None:
    """Concatenate the shards, set flagged rows aside and write the three splits.

    Rows the simulator flagged go to ``failures`` (CSV with parameters and reason)
    and out of the splits; more than ``max_failure_fraction`` of them is an error
    (the shards stay on disk, nothing is lost). ``manifest`` (JSON) records seed,
    prior bounds, counts, failures and the package version.
    """
    shard_paths = list(shards) if not isinstance(shards, str) else [shards]
    df = pd.concat([read_dataset(p) for p in shard_paths], ignore_index=True)
    if not df["sample"].is_monotonic_increasing or df["sample"].duplicated().any():
        raise DataError("shards are not in sample order or overlap: " + ", ".join(shard_paths))
    bad = df["status"] != "ok"
    n_bad = int(bad.sum())
    fails = df[bad]
    Path(failures).parent.mkdir(parents=True, exist_ok=True)
    fails[["sample", "status", *PARAMETER_NAMES]].to_csv(failures, index=False)
    frac = n_bad / max(len(df), 1)
    if frac > max_failure_fraction:
        reasons = fails["status"].value_counts().to_dict()
        raise DataError(
            f"{study}: {n_bad} of {len(df)} simulated rows flagged ({frac:.2%}), above "
            f"data.max_failure_fraction = {max_failure_fraction:.2%}; reasons: {reasons}; "
            f"rows listed in {failures}. Narrow the prior or raise the threshold."
        )
    good = df[~bad].drop(columns=["status"]).reset_index(drop=True)
    sizes = split_sizes(len(good), int(split["validation"]), float(split["train_fraction"]))
    n_tr, n_te = sizes["train"], sizes["test"]
    parts = {"train": good.iloc[:n_tr], "test": good.iloc[n_tr:n_tr + n_te],
             "validation": good.iloc[n_tr + n_te:]}
    for name, path in (("train", train), ("test", test), ("validation", validation)):
        write_dataset(parts[name].reset_index(drop=True), path)
    lo, hi = priors.prior_bounds(prior)
    info = {
        "study": study,
        "seed": int(seed),
        "package_version": __version__,
        "n_samples": int(len(df)),
        "n_failed": n_bad,
        "failures_by_reason": {str(k): int(v) for k, v in fails["status"].value_counts().items()},
        "split_sizes": sizes,
        "split_rule": {"validation": int(split["validation"]), "train_fraction": float(split["train_fraction"])},
        "prior": prior,
        "prior_bounds": {n: [float(a), float(b)] for n, a, b in zip(PARAMETER_NAMES, lo, hi)},
        "units": {**{p: PARAMETER_BY_NAME[p].unit for p in PARAMETER_NAMES},
                  **{o: OUTPUT_BY_NAME[o].unit for o in OUTPUT_NAMES}},
        "simulator": dict(simulator),
    }
    Path(manifest).write_text(json.dumps(info, indent=2) + "\n")
    log.info("%s: %s (%d flagged)", study, sizes, n_bad)


#: Bins of each column's histogram (equal widths over the column's range).
HISTOGRAM_BINS = 50


def histogram_counts(train: str, test: str, validation: str, counts: str, bins: int = HISTOGRAM_BINS) -> None:
    """Histograms of the 23 inputs and 16 outputs over all rows of a study's three splits, to
    the CSV ``counts``: one row per column and bin (``column``, ``bin``, its edges ``left`` and
    ``right`` in the column's registry unit, ``count``). ``bins`` equal bins span each column's
    range, the last one closed (``numpy.histogram``); Hr, a parameter and an output, is listed once."""
    df = pd.concat([read_dataset(p) for p in (train, test, validation)], ignore_index=True)
    parts = []
    for name in dict.fromkeys(PARAMETER_NAMES + OUTPUT_NAMES):
        n, edges = np.histogram(df[name].to_numpy(), bins=int(bins))
        parts.append(pd.DataFrame({"column": name, "bin": np.arange(len(n)), "left": edges[:-1],
                                   "right": edges[1:], "count": n}))
    Path(counts).parent.mkdir(parents=True, exist_ok=True)
    pd.concat(parts, ignore_index=True).to_csv(counts, index=False)
    log.info("histograms of %d columns over %d rows (%d bins each)", len(parts), len(df), bins)
