"""Global sensitivity of the 16 outputs to the 23 parameters: Sobol indices (SALib), and what
they say beside the structural study's two identifiability verdicts.

Design: SALib's Sobol sampler (Saltelli 2010 scheme on a scrambled Sobol sequence, no
second-order terms): ``n_base`` base points give ``n_base (d + 2)`` parameter sets, simulated
on the batch path. Estimators: Saltelli 2010 (first order S1), Jansen (total ST); confidence
half-widths by bootstrap over the base points. The first ``n`` base points of the sequence
are themselves a balanced design, so the indices at ``n_base / 4`` and ``n_base / 2`` (the
convergence check) come from the same simulations. A base point with any set the simulator
flags is left out with all its sets (their count is reported).

S1 is the share of an output's variance over the prior explained by one parameter alone, ST
the share it is involved in (with interactions); both are unitless, in [0, 1] up to Monte Carlo
error. Influence is not identifiability: a parameter can carry a large ST and still be
unidentifiable when others can compensate it (:func:`verdict_table`).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.data.priors import prior_bounds
from cvsim6.model import solver
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES
from cvsim6.table_files import to_markdown, write_table
from cvsim6.seeding import derived_seed

log = logging.getLogger(__name__)

#: Random streams (of the master seed) of the Sobol design and of the bootstrap.
SAMPLE_STREAM, BOOTSTRAP_STREAM = 4101, 4102
#: Columns of the Sobol table, in order.
COLUMNS = ["prior", "output", "parameter", "S1", "S1_conf", "ST", "ST_conf"]


def _salib_seed(seed: int, stream: int) -> int:
    """A non-zero seed (SALib's analyze ignores a seed of 0)."""
    return max(1, derived_seed(seed, stream) % (2**32))


def problem(lo: np.ndarray, hi: np.ndarray, names=PARAMETER_NAMES) -> dict:
    """SALib problem of independent uniform parameters on ``[lo, hi]`` (registry units)."""
    return {"num_vars": len(names), "names": list(names), "bounds": [[float(a), float(b)] for a, b in zip(lo, hi)]}


def check_n_base(n_base: int) -> int:
    """``n_base`` as an int; a power of 2 of at least 16 (Sobol balance properties, and the
    subsets n/4, n/2 of the convergence check), else ValueError naming the value."""
    n = int(n_base)
    if n < 16 or n & (n - 1):
        raise ValueError(f"sobol n_base = {n_base} must be a power of 2 and at least 16 (e.g. 1024, 8192)")
    return n


def design(prob: dict, n_base: int, seed: int) -> np.ndarray:
    """SALib Sobol design, (n_base (d + 2), d), seeded (bit-reproducible)."""
    from SALib.sample import sobol

    return sobol.sample(prob, check_n_base(n_base), calc_second_order=False, scramble=True,
                        seed=_salib_seed(seed, SAMPLE_STREAM))


def indices(prob: dict, Y: np.ndarray, n_base: int, seed: int, num_resamples: int = 100,
            conf_level: float = 0.95) -> pd.DataFrame:
    """S1, S1_conf, ST, ST_conf of every parameter for each column of ``Y`` (rows of the design
    of :func:`design`, in order) from its first ``n_base`` base points; base points with a
    non-finite row are left out. One row per (output column, parameter)."""
    from SALib.analyze import sobol

    d = prob["num_vars"]
    block = np.asarray(Y, float)[: int(n_base) * (d + 2)].reshape(int(n_base), d + 2, -1)
    keep = np.isfinite(block).all(axis=(1, 2))
    rows = []
    for k in range(block.shape[2]):
        y = block[keep, :, k].reshape(-1)
        if len(y) == 0 or not np.std(y) > 0:
            res = {key: np.full(d, np.nan) for key in ("S1", "S1_conf", "ST", "ST_conf")}
        else:
            res = sobol.analyze(prob, y, calc_second_order=False, num_resamples=int(num_resamples),
                                conf_level=float(conf_level), seed=_salib_seed(seed, BOOTSTRAP_STREAM))
        for j in range(d):
            rows.append({"output": k, "parameter": prob["names"][j], "S1": float(res["S1"][j]),
                         "S1_conf": float(res["S1_conf"][j]), "ST": float(res["ST"][j]),
                         "ST_conf": float(res["ST_conf"][j]), "n_base": int(keep.sum())})
    return pd.DataFrame(rows)


def sobol_prior(indices_csv: str, prior_name: str, prior: dict, simulator: dict, n_base: int,
                bootstrap: int, conf_level: float, seed: int) -> None:
    """Workflow step: Sobol indices of the 16 outputs under one prior at ``n_base / 4``,
    ``n_base / 2`` and ``n_base`` base points (CSV: the columns of :data:`COLUMNS`, ``n_base``:
    the base points used, ``design_base``: the design's size they come from)."""
    n = check_n_base(n_base)
    lo, hi = prior_bounds(prior)
    prob = problem(lo, hi)
    X = design(prob, n, seed)
    log.info("prior %s: %d base points, %d simulations", prior_name, n, len(X))
    Y, status = solver.simulate_batch(X, steps_per_cycle=simulator["steps_per_cycle"], n_cycles=simulator["n_cycles"],
                                      window_cycles=simulator["window_cycles"], invalid="flag", progress=True)
    Y[status != 0] = np.nan
    log.info("prior %s: %d of %d sets flagged by the simulator", prior_name, int((status != 0).sum()), len(X))
    frames = []
    for size in (n // 4, n // 2, n):
        df = indices(prob, Y, size, seed, bootstrap, conf_level)
        df.insert(0, "design_base", size)
        frames.append(df)
    out = pd.concat(frames, ignore_index=True)
    out["output"] = [OUTPUT_NAMES[k] for k in out["output"]]
    out.insert(0, "prior", prior_name)
    Path(indices_csv).parent.mkdir(parents=True, exist_ok=True)
    out.to_csv(indices_csv, index=False)


def sobol_tables(indices: list[str], csv: str, md: str, convergence_csv: str, convergence_md: str) -> None:
    """Workflow step: the Sobol table at the full design (:data:`COLUMNS` and ``n_base``), its
    Markdown summary (largest ST per output), and the convergence table: per prior and design
    size, the largest change of S1 and ST against the full design and the largest bootstrap
    half-width."""
    allp = pd.concat([pd.read_csv(p) for p in indices], ignore_index=True)
    full = allp[allp["design_base"] == allp.groupby("prior")["design_base"].transform("max")]
    table = full[COLUMNS + ["n_base"]].reset_index(drop=True)
    Path(csv).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(csv, index=False)
    top = []
    for (prior, output), g in table.groupby(["prior", "output"], sort=False):
        g = g.nlargest(3, "ST")
        top.append({"prior": prior, "output": output,
                    "largest ST": ", ".join(f"{p} {v:.2f}" for p, v in zip(g["parameter"], g["ST"]))})
    Path(md).write_text(to_markdown(pd.DataFrame(top), "Sobol total indices: the three largest per output and "
                                    f"prior ({int(table['n_base'].max())} base points at most; all in the CSV)"),
                        encoding="utf-8")
    conv = convergence(allp)
    write_table(conv, convergence_csv, convergence_md,
                caption="Convergence of the Sobol indices: largest absolute change of S1 and ST over outputs and "
                        "parameters between each design and the full one, and the largest bootstrap half-width")


def convergence(allp: pd.DataFrame) -> pd.DataFrame:
    """Per prior and design size: max |S1 - S1(full)|, max |ST - ST(full)|, max S1_conf, max ST_conf."""
    rows = []
    for prior, g in allp.groupby("prior", sort=False):
        full = g[g["design_base"] == g["design_base"].max()].set_index(["output", "parameter"])
        for size, h in g.groupby("design_base"):
            h = h.set_index(["output", "parameter"]).loc[full.index]
            rows.append({"prior": prior, "design_base": int(size),
                         "max abs dS1 vs full": float(np.nanmax(np.abs(h["S1"] - full["S1"]))),
                         "max abs dST vs full": float(np.nanmax(np.abs(h["ST"] - full["ST"]))),
                         "max S1_conf": float(np.nanmax(h["S1_conf"])), "max ST_conf": float(np.nanmax(h["ST_conf"]))})
    return pd.DataFrame(rows)


#: Why the three verdicts disagree, by (influential, locally non-identifiable, free on the manifold).
WHY = {
    (True, False, False): "",
    (False, True, True): "",
    (True, True, True): "influential, yet compensated: other parameters can undo its effect on every output "
                        "(ST measures influence, not identifiability)",
    (True, True, False): "influential and in the local null space, but inVAErt's manifold at y* barely moves it: "
                         "the null direction is short inside the prior box, or the decoder under-spreads it",
    (True, False, True): "influential and locally identifiable, yet inVAErt spreads it: more spread than the "
                         "simulator allows (a decoder error), or the manifold curves away from the Jacobian points",
    (False, False, False): "small share of the output variance over the prior, yet its effect exceeds the "
                           "measurement noise: precision near y*, not variance over the prior",
    (False, False, True): "small variance share and free on the manifold, but locally identifiable: its "
                          "effect is near the noise level (the rank threshold counts it)",
    (False, True, False): "no output depends on it much, yet inVAErt does not spread it: the decoder "
                          "under-represents this non-identifiable direction",
}


def verdict_table(sobol: pd.DataFrame, local: pd.DataFrame, prior: str, influence_threshold: float,
                  nonidentifiable_share: float, spread_threshold: float) -> pd.DataFrame:
    """Per parameter: its largest total index over the outputs under ``prior`` (and the output),
    the structural study's mean Jacobian null-space share and inVAErt manifold spread (fraction of
    the prior width, 95%), the three verdicts, whether they agree, and why not (:data:`WHY`)."""
    s = sobol[sobol["prior"] == prior]
    if s.empty:
        raise ValueError(f"no Sobol indices for prior {prior!r}; have {sorted(sobol['prior'].unique())}")
    best = s.loc[s.groupby("parameter")["ST"].idxmax()].set_index("parameter")
    loc = local.set_index("Parameter")
    rows = []
    for name in PARAMETER_NAMES:
        st, share = float(best.at[name, "ST"]), float(loc.at[name, "null-space share (mean)"])
        spread = float(loc.at[name, "manifold spread / prior width (95%)"])
        key = (st >= influence_threshold, share > nonidentifiable_share, spread >= spread_threshold)
        rows.append({"Parameter": name, "max ST": st, "output of max ST": best.at[name, "output"],
                     "null-space share": share, "manifold spread": spread,
                     "Sobol": "influential" if key[0] else "negligible",
                     "Jacobian": "non-identifiable" if key[1] else "identifiable",
                     "inVAErt": "free" if key[2] else "pinned",
                     "agree": "yes" if key in ((True, False, False), (False, True, True)) else "no",
                     "why not": WHY[key]})
    return pd.DataFrame(rows)


def sensitivity_identifiability(sobol: str, local: str, csv: str, md: str, prior: str, influence_threshold: float,
                                nonidentifiable_share: float, spread_threshold: float) -> None:
    """Workflow step: :func:`verdict_table` from the Sobol table and the structural study's
    local identifiability table, as CSV and Markdown."""
    table = verdict_table(pd.read_csv(sobol), pd.read_csv(local), prior, influence_threshold,
                          nonidentifiable_share, spread_threshold)
    n = int((table["agree"] == "yes").sum())
    write_table(table, csv, md, caption=f"Three verdicts per parameter ({prior} prior): Sobol (largest total index "
                                        f">= {influence_threshold:g}: influential), the local Jacobian check "
                                        f"(mean null-space share > {nonidentifiable_share:g}: non-identifiable) "
                                        f"and inVAErt's manifold at y* (95% spread >= {spread_threshold:g} of the "
                                        f"prior width: free); they agree for {n} of {len(table)} parameters")
