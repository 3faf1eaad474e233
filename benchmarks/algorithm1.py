"""Algorithm 1 (paper section 3.3.3) at two flow-sample counts, side by side: CPU seconds per
patient and noise level, and the EHR reconstruction error e_k (the paper's table 5).

Reads a finished run of the workflow (``--root``, default this checkout): the EHR networks
``results/models/ehr/{flow,encoder_decoder}_delta<d>.pt`` and ``emulator.pt``, the selected
patients ``results/ehr/patients.csv`` and the reference rows ``results/data/ehr/validation.parquet``.
Per noise level it times, on one torch thread (``time.process_time``):

- the completion step alone (steps 1-4), with one sample stream per patient (the workflow's
  scheme before shared streams: seed + 7919 k for patient k) and with one stream shared by every
  patient (:func:`cvsim6.inference.inversion.complete_missing_shared`), at ``--low`` samples;
- the whole inversion (:func:`cvsim6.studies.ehr.invert_observations`: completion, decoding of
  N_w latent draws, emulation, OOD score) at ``--low`` and ``--high`` samples, and e_k of each.

    .venv/bin/python benchmarks/algorithm1.py --root <run checkout> --noise-levels 0.25 0.5 1 2

The inversion settings (latent draws, OOD reference, corrector rounds, M by default) and the
seed are the run's config's (``--config``, default ``<root>/config/config.yaml``).

Output: the tables on stdout, and ``benchmarks/results/algorithm1.json`` (``--name`` for another).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

#: The seed offset per patient of the per-patient scheme (the workflow's before shared streams).
PER_PATIENT_SEED_STEP = 7919


def completion_cpu_seconds(flow, y: np.ndarray, n_samples: int, seed: int) -> dict[str, float]:
    """CPU seconds of Algorithm 1's completion of every row of ``y`` (n, 16): one stream per row
    (seeds ``seed + 7919 k``) against one shared stream (``seed``)."""
    from cvsim6.inference import inversion

    t0 = time.process_time()
    for k, row in enumerate(y):
        inversion.complete_missing(flow, row, n_samples, seed=seed + PER_PATIENT_SEED_STEP * k)
    t1 = time.process_time()
    inversion.complete_missing_shared(flow, y, n_samples, seed=seed)
    t2 = time.process_time()
    return {"per_patient": t1 - t0, "shared": t2 - t1}


def inversion_run(networks: dict, patients: pd.DataFrame, y_ref: np.ndarray, n_samples: int,
                  settings: dict) -> tuple[float, pd.DataFrame]:
    """CPU seconds of the whole inversion of ``patients`` with ``n_samples`` flow samples, and
    its e_k table (:func:`cvsim6.studies.ehr.error_per_output`)."""
    from cvsim6.studies.ehr import error_per_output, invert_observations

    t0 = time.process_time()
    pred = invert_observations(patients, networks["flow"], networks["encdec"], networks["emulator"],
                               n_flow_samples=n_samples, reference_outputs=y_ref,
                               on_warning=lambda pid, msg: None, **settings)
    return time.process_time() - t0, error_per_output(patients, pred)


def measure(root: Path, deltas: list[float], low: int, high: int, settings: dict,
            min_count: int = 10) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The timing table (one row per noise level) and the e_k table (one row per output and
    noise level) of the run at ``root``; geometric means over the outputs seen in more than
    ``min_count`` patients."""
    from cvsim6 import paper_values
    from cvsim6.data.datasets import load_split
    from cvsim6.nets.io import load_model
    from cvsim6.registry import OUTPUT_NAMES
    from cvsim6.reporting.scorecard import geomean_ratio

    results = root / "results"
    patients = pd.read_csv(results / "ehr" / "patients.csv", index_col="patient")[list(OUTPUT_NAMES)]
    _, y_ref = load_split(results / "data" / "ehr" / "validation.parquet")
    y = patients.to_numpy(float)
    y = y[np.isfinite(y).any(axis=1)]
    n = len(patients)
    timing, errors = [], []
    for d in deltas:
        tag = f"{d:g}"
        nets = {"flow": load_model(results / "models" / "ehr" / f"flow_delta{tag}.pt"),
                "encdec": load_model(results / "models" / "ehr" / f"encoder_decoder_delta{tag}.pt"),
                "emulator": load_model(results / "models" / "ehr" / "emulator.pt")}
        step = completion_cpu_seconds(nets["flow"], y, low, settings["seed"])
        cpu_low, e_low = inversion_run(nets, patients, y_ref, low, settings)
        cpu_high, e_high = inversion_run(nets, patients, y_ref, high, settings)
        i = list(paper_values.EHR_DELTAS).index(d) if d in paper_values.EHR_DELTAS else None
        seen = e_low.index[e_low["count"] > min_count]
        paper = [paper_values.EHR_EK[o][i] for o in seen] if i is not None else None
        timing.append({"noise_level": d, "patients": n,
                       f"completion per-patient streams, M={low:,} (CPU s/patient)": step["per_patient"] / n,
                       f"completion shared stream, M={low:,} (CPU s/patient)": step["shared"] / n,
                       f"inversion, M={low:,} (CPU s/patient)": cpu_low / n,
                       f"inversion, M={high:,} (CPU s/patient)": cpu_high / n,
                       "high / low (inversion CPU)": cpu_high / cpu_low,
                       f"e_k / paper, M={low:,}": geomean_ratio(e_low.loc[seen, "e_k"], paper) if paper else np.nan,
                       f"e_k / paper, M={high:,}": geomean_ratio(e_high.loc[seen, "e_k"], paper) if paper else np.nan})
        for o in e_low.index:
            errors.append({"noise_level": d, "output": o, "count": int(e_low.loc[o, "count"]),
                           f"e_k, M={low:,}": e_low.loc[o, "e_k"], f"e_k, M={high:,}": e_high.loc[o, "e_k"],
                           "paper": paper_values.EHR_EK[o][i] if i is not None else np.nan})
    return pd.DataFrame(timing), pd.DataFrame(errors)


#: The workflow's Algorithm 1 settings (config ``ehr_study``) the inversion takes besides M.
SETTINGS = ("n_latent", "n_reference", "reference_flow_samples", "corrector_steps")


def inversion_settings(cfg: dict, seed: int | None = None) -> dict:
    """The EHR inversion's settings of the workflow config ``cfg`` (:data:`SETTINGS`), with the
    master ``seed`` (default: the config's)."""
    study = cfg["ehr_study"]
    return {"seed": int(cfg["seed"] if seed is None else seed), **{k: int(study[k]) for k in SETTINGS}}


def main(argv: list[str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path("."), help="a finished run's checkout")
    parser.add_argument("--config", type=Path, default=None,
                        help="the run's config (default <root>/config/config.yaml)")
    parser.add_argument("--noise-levels", type=float, nargs="+", default=[0.25, 0.5, 1.0, 2.0])
    parser.add_argument("--low", type=int, default=None, help="flow samples per patient (default: the config's)")
    parser.add_argument("--high", type=int, default=5_100_000, help="flow samples per patient, the paper's")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--seed", type=int, default=None, help="the run's master seed (default: the config's)")
    parser.add_argument("--name", default="algorithm1", help="result file name, under benchmarks/results/")
    import results_io
    import torch
    import yaml

    results_io.add_note_argument(parser)
    args = parser.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/algorithm1.py", *argv])
    torch.set_num_threads(args.threads)
    cfg = yaml.safe_load((args.config or args.root / "config" / "config.yaml").read_text())
    settings = inversion_settings(cfg, args.seed)
    args.low = int(cfg["ehr_study"]["n_flow_samples"]) if args.low is None else args.low
    timing, errors = measure(args.root.resolve(), args.noise_levels, args.low, args.high, settings)
    print(timing.to_string(float_format="%.4g"))
    print(errors.to_string(float_format="%.4g"))
    levels = "" if args.name == "algorithm1" else f" (noise levels {', '.join(f'{d:g}' for d in args.noise_levels)})"
    run.save(args.name, f"Algorithm 1: CPU time per patient and e_k at two flow-sample counts{levels}",
             f"Algorithm 1 on the EHR patients with a finished run's networks, one torch thread: the completion "
             f"step alone with one sample stream per patient against one stream shared by all patients, and the "
             f"whole inversion (completion, {settings['n_latent']} latent draws decoded, emulation, OOD score) at "
             f"{args.low:,} and {args.high:,} flow samples per patient, with e_k (table 5) of each. e_k / paper: "
             f"geometric mean of the ratios over the outputs seen in more than 10 patients.",
             [results_io.table(timing, "cpu_per_patient", "Per noise level: CPU seconds per patient of each "
                               "variant, and e_k over the paper's.", {c: ".4g" for c in timing.columns[2:]}),
              results_io.table(errors, "ek", "e_k per output and noise level at both sample counts, and the "
                               "paper's.", {c: ".4g" for c in errors.columns[3:]})],
             parameters={"root": results_io.portable(str(args.root.resolve())), "noise_levels": args.noise_levels,
                         "low": args.low, "high": args.high, "threads": args.threads, **settings},
             note=args.note)
    return timing, errors


if __name__ == "__main__":
    main()
