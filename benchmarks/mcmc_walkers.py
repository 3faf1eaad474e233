"""Benchmark: at an equal simulation budget, do more emcee walkers (and fewer steps) give the
MCMC reference posteriors better convergence?

The workflow's reference posteriors (:func:`cvsim6.studies.references.reference_mcmc`) run 48
walkers for up to 14,000 steps (DE 80% / DE-snooker 20% moves, unit prior box, the chain's
second half kept) and judge them by ArviZ's R-hat and ESS with the walkers as chains. This
script reruns chosen cases of a finished run's ``cases.csv`` with the same posterior (the EHR
prior box, the Gaussian likelihood with standard deviation ``noise_level`` times each output's
noise scale, the config's simulator settings), the same start procedure
(:func:`cvsim6.inference.reference_posterior.start_walkers` with the config's prior draws and
Levenberg-Marquardt iterations) and the same per-case seed (``derived_seed(seed, MCMC_STREAM +
position)``), changing only the number of walkers W and the number of steps, ``budget // W``:
every variant gets the same walker-steps (proposals) of MCMC. Each chain runs to its steps in
one go (no convergence checks, no extension), one process, one thread. Per case and W it
records R-hat max and ESS min (min of bulk and tail) over the parameters, how many parameters
miss R-hat <= 1.05 and ESS >= 400, the acceptance, the simulations and CPU seconds of the start
and of the MCMC, ESS min per MCMC CPU second and its ratio to the config's W (the workflow's
setting, the baseline, measured in the same run). The start's cost grows with W and is not in
the budget. With ``--diagnostics`` (the run's ``reference_posterior_diagnostics.csv``) the
workflow's own R-hat max and ESS min stand beside the baseline's, which repeat them when the
baseline's steps are the workflow's.

    .venv/bin/python benchmarks/mcmc_walkers.py --cases <run>/results/references/cases.csv \\
        --diagnostics <run>/results/tables/reference_posterior_diagnostics.csv

Output: the table on stdout, and ``benchmarks/results/mcmc_walkers.json``.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

if __name__ == "__main__":  # one BLAS thread, as the workflow's single-thread job (not when a test imports this)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: Walker-steps per variant: the workflow's 48 walkers x 14,000 steps.
DEFAULT_BUDGET = 48 * 14_000
#: Number formats of the result table on the page.
FORMATS = {"rhat_max": ".4f", "ess_min": ".0f", "acceptance": ".3f", "start_simulations": ",d",
           "mcmc_simulations": ",d", "start_cpu_s": ".0f", "mcmc_cpu_s": ".0f", "ess_min_per_cpu_s": ".3g",
           "ess_per_cpu_vs_baseline": ".2f", "workflow_rhat_max": ".4f", "workflow_ess_min": ".0f"}


def steps_for(budget: int, walkers: int) -> int:
    """Steps per walker of a variant: ``budget // walkers`` walker-steps; at least 4, so that
    the kept second half of the chain splits in two for R-hat."""
    steps = int(budget) // int(walkers)
    if steps < 4:
        raise ValueError(f"budget {budget} gives {walkers} walkers only {steps} steps (need >= 4)")
    return steps


def load_settings(config: Path) -> dict:
    """The settings of ``reference_mcmc`` in a workflow config: the EHR prior, the simulator,
    the noise level, the ``references.mcmc`` entry and the master seed."""
    cfg = yaml.safe_load(Path(config).read_text())
    return {"prior": cfg["data"]["studies"]["ehr"]["prior"], "simulator": cfg["simulator"],
            "noise_level": float(cfg["references"]["noise_level"]), "mcmc": dict(cfg["references"]["mcmc"]),
            "seed": int(cfg["seed"])}


def case_posterior(cases: Path, case: str, settings: dict):
    """The posterior of ``case`` as ``reference_mcmc`` builds it, its row and its MCMC seed."""
    from cvsim6.data.priors import prior_bounds
    from cvsim6.inference import reference_posterior as rp
    from cvsim6.registry import OUTPUT_NAMES, noise_std
    from cvsim6.seeding import derived_seed
    from cvsim6.studies import references

    row, position = references._case_row(str(cases), case)
    lo, hi = prior_bounds(settings["prior"])
    y = row[[f"y_{n}" for n in OUTPUT_NAMES]].to_numpy(float)
    post = rp.BoxPosterior(rp.simulator_function(settings["simulator"]), y,
                           settings["noise_level"] * noise_std(), lo, hi)
    return post, row, derived_seed(settings["seed"], references.MCMC_STREAM + position)


def summarise(diag: dict, rhat_max: float = 1.05, ess_min: float = 400.0) -> dict:
    """R-hat max and ESS min (of bulk and tail) over the parameters of ``diag`` (the arrays of
    :func:`cvsim6.inference.reference_posterior.convergence`), how many parameters miss each
    target, and whether every parameter meets both."""
    rhat = np.asarray(diag["rhat"], float)
    ess = np.minimum(np.asarray(diag["ess_bulk"], float), np.asarray(diag["ess_tail"], float))
    return {"rhat_max": float(rhat.max()), "ess_min": float(ess.min()),
            "n_rhat_over": int((~(rhat <= rhat_max)).sum()), "n_ess_under": int((~(ess >= ess_min)).sum()),
            "converged": bool((rhat <= rhat_max).all() and (ess >= ess_min).all())}


def run_variant(cases: Path, case: str, walkers: int, steps: int, settings: dict) -> dict:
    """One case with ``walkers`` walkers for ``steps`` steps, started and seeded as the
    workflow does: its table row."""
    from cvsim6.inference import reference_posterior as rp

    mc = settings["mcmc"]
    post, row, seed = case_posterior(cases, case, settings)
    cpu0 = time.process_time()
    start = rp.start_walkers(post, int(walkers), np.random.default_rng(seed), int(mc["start_prior_draws"]),
                             int(mc["start_iterations"]))
    start_cpu, start_sims = time.process_time() - cpu0, post.evaluations
    res = rp.run_ensemble(post, start, seed, steps, steps, steps, float(mc["rhat_max"]), float(mc["ess_min"]))
    out = {"case": case, "kind": row["kind"], "walkers": int(walkers), "steps": int(res["steps"]),
           "workflow_setting": int(walkers) == int(mc["walkers"]) and int(res["steps"]) == int(mc["max_steps"])}
    out.update(summarise(res, float(mc["rhat_max"]), float(mc["ess_min"])))
    out.update({"acceptance": res["acceptance"], "start_simulations": int(start_sims),
                "mcmc_simulations": int(res["evaluations"]), "start_cpu_s": start_cpu,
                "mcmc_cpu_s": res["mcmc_cpu_seconds"], "ess_min_per_cpu_s": out["ess_min"] / res["mcmc_cpu_seconds"]})
    return out


def add_baseline_ratios(table: pd.DataFrame, baseline_walkers: int) -> pd.DataFrame:
    """``ess_per_cpu_vs_baseline``: each row's ESS min per CPU second over that of the same
    case's row with ``baseline_walkers`` walkers (NaN where the case has none)."""
    table = table.copy()
    base = table[table["walkers"] == int(baseline_walkers)].set_index("case")["ess_min_per_cpu_s"]
    table["ess_per_cpu_vs_baseline"] = table["ess_min_per_cpu_s"] / table["case"].map(base).astype(float)
    return table


def add_workflow_diagnostics(table: pd.DataFrame, diagnostics: Path | None, baseline_walkers: int) -> pd.DataFrame:
    """The workflow's recorded R-hat max and ESS min of each case (its
    ``reference_posterior_diagnostics.csv``) on the rows with ``baseline_walkers``; NaN elsewhere."""
    table = table.copy()
    table["workflow_rhat_max"] = np.nan
    table["workflow_ess_min"] = np.nan
    if diagnostics is None:
        return table
    wf = pd.read_csv(diagnostics).set_index("case")
    on = (table["walkers"] == int(baseline_walkers)) & table["case"].isin(wf.index)
    table.loc[on, "workflow_rhat_max"] = table.loc[on, "case"].map(wf["rhat_max"]).astype(float)
    table.loc[on, "workflow_ess_min"] = table.loc[on, "case"].map(wf["ess_min"]).astype(float)
    return table


def measure(cases: Path, names: list[str], walkers: list[int], budget: int, settings: dict) -> pd.DataFrame:
    """Every case with every number of walkers at ``budget`` walker-steps each, one after the
    other; each row printed as it finishes."""
    rows = []
    for case in names:
        for w in walkers:
            row = run_variant(cases, case, w, steps_for(budget, w), settings)
            print(f"{case}: {w} walkers x {row['steps']} steps: R-hat max {row['rhat_max']:.4f}, ESS min "
                  f"{row['ess_min']:.0f}, {row['n_rhat_over']} / {row['n_ess_under']} parameters short, "
                  f"acceptance {row['acceptance']:.3f}, {row['mcmc_cpu_s']:.0f} s CPU", flush=True)
            rows.append(row)
    return pd.DataFrame(rows)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=Path, required=True, help="a finished run's results/references/cases.csv")
    parser.add_argument("--case", action="append", default=None, help="a case (repeatable; default ehr9, sim0)")
    parser.add_argument("--walkers", type=int, nargs="+", default=[48, 96, 192], help="numbers of walkers")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET, help="walker-steps of MCMC per variant")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml", help="the run's config")
    parser.add_argument("--diagnostics", type=Path, default=None,
                        help="the run's reference_posterior_diagnostics.csv, beside the baseline")
    return parser


def main(argv: list[str] | None = None) -> pd.DataFrame:
    import results_io

    parser = _parser()
    results_io.add_note_argument(parser)
    args = parser.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/mcmc_walkers.py", *argv])
    names = args.case or ["ehr9", "sim0"]
    settings = load_settings(args.config)
    mc = settings["mcmc"]
    base_w = int(mc["walkers"])
    table = measure(args.cases.resolve(), names, args.walkers, args.budget, settings)
    table = add_workflow_diagnostics(add_baseline_ratios(table, base_w), args.diagnostics, base_w)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(table.to_string(index=False, float_format="%.4g"))
    run.save("mcmc_walkers", "MCMC reference posteriors: more walkers, fewer steps, at an equal budget",
             f"The workflow's MCMC reference posterior (emcee, DE 80% / DE-snooker 20% moves, the chain's second half "
             f"kept, ArviZ R-hat and ESS with walkers as chains) of cases {', '.join(names)} of a finished run, "
             f"rerun with the workflow's posterior, start procedure and per-case seed, changing only the walkers W "
             f"and the steps, {args.budget:,} // W, so that every variant gets the same {args.budget:,} walker-steps "
             f"of MCMC (the start's simulations grow with W and are apart). No convergence checks or extension; one "
             f"process, one thread. W = {base_w} is the workflow's setting (the baseline; workflow_setting: also "
             f"its {int(mc['max_steps']):,} steps), run in the same measurement; workflow_rhat_max and "
             f"workflow_ess_min are the run's own diagnostics of that case, for comparison. Targets: R-hat <= "
             f"{float(mc['rhat_max']):g} and ESS >= {float(mc['ess_min']):g} for every one of the 23 parameters.",
             [results_io.table(table, "walkers", "Per case and number of walkers: R-hat max and ESS min (min of "
                               "bulk and tail) over the parameters, parameters short of each target, acceptance, "
                               "simulations and CPU seconds of start and MCMC, ESS min per MCMC CPU second and its "
                               f"ratio to W = {base_w}'s.", FORMATS)],
             parameters={"cases": results_io.portable(str(args.cases.resolve())), "case": names,
                         "walkers": args.walkers, "budget": args.budget,
                         "config": results_io.portable(str(args.config.resolve())),
                         "diagnostics": results_io.portable(str(args.diagnostics.resolve()))
                         if args.diagnostics else None, **settings},
             note=args.note)
    return table


if __name__ == "__main__":
    main()
