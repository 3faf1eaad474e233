"""Benchmark: which network carries the gap between our e_k and the paper's? Swap the flow and
the encoder/decoder between our trained EHR networks and the published ones.

For each noise level, inverts the workflow's selected EHR patients (``results/ehr/patients.csv``)
with the workflow's inversion (:func:`cvsim6.studies.ehr.invert_observations`: Algorithm 1 with the
flow, then the encoder/decoder's latent draws through the emulator) four times: every network
ours, every network published, and each of the two swaps. The flow completes the missing
outputs; the encoder/decoder and the emulator it was trained through decode and re-evaluate, so
they move together. e_k per output as table 5 (:func:`cvsim6.studies.ehr.error_per_output`), and
its geometric mean of ours/paper over the outputs seen in more than
:data:`cvsim6.reporting.scorecard.MIN_PATIENTS_EXCLUSIVE` patients (the scorecard's headline).
Same seed, samples and draws for every combination; one thread.

    .venv/bin/python benchmarks/ehr_network_swap.py --run <run> --deltas 0.5

``<run>``: a finished run of ``all`` and of the published networks (``results/models/ehr/`` and
``results/published/models/ehr/``). Output: the table on stdout and
``benchmarks/results/ehr_network_swap.json``.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

if __name__ == "__main__":  # one BLAS thread (not when a test imports this)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COMBINATIONS = (("ours", "ours"), ("published", "ours"), ("ours", "published"), ("published", "published"))
FORMATS = {"e_k / paper": ".3f", "cpu_seconds": ".0f"}


def ek_ratio(e_k: pd.DataFrame, delta: float) -> tuple[float, dict[str, float]]:
    """Geometric mean over the scorecard's outputs (:func:`cvsim6.reporting.scorecard.counted_outputs`:
    seen in more than 10 patients, given by the paper) of e_k / the paper's e_k at ``delta`` (one of
    the paper's levels), and each output's ratio.
    ``e_k``: :func:`cvsim6.studies.ehr.error_per_output`'s table (index: output names)."""
    from cvsim6 import paper_values
    from cvsim6.reporting.scorecard import counted_outputs, geomean_ratio

    i = list(paper_values.EHR_DELTAS).index(float(delta))
    seen = counted_outputs(e_k["count"])
    ours = e_k.loc[seen, "e_k"].to_numpy(float)
    paper = np.array([paper_values.EHR_EK[k][i] for k in seen], float)
    return geomean_ratio(ours, paper), dict(zip(seen, ours / paper))


def main(argv: list[str] | None = None) -> pd.DataFrame:
    import results_io
    import torch

    from cvsim6.data.datasets import load_split
    from cvsim6.nets import load_model
    from cvsim6.registry import OUTPUT_NAMES
    from cvsim6.studies.ehr import error_per_output, invert_observations

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True, help="a finished run's folder")
    p.add_argument("--deltas", type=float, nargs="+", default=[0.5])
    p.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    results_io.add_note_argument(p)
    args = p.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/ehr_network_swap.py", *argv])
    torch.set_num_threads(1)
    cfg = yaml.safe_load(args.config.read_text())
    study, seed = cfg["ehr_study"], int(cfg["seed"])
    res = args.run / "results"
    models = {"ours": res / "models" / "ehr", "published": res / "published" / "models" / "ehr"}
    patients = pd.read_csv(res / "ehr" / "patients.csv", index_col="patient")
    obs = patients[list(OUTPUT_NAMES)]
    _, y_ref = load_split(str(res / "data" / "ehr" / "validation.parquet"))
    rows, per_output = [], []
    for delta in args.deltas:
        tag = f"{delta:g}"
        for flow_src, ed_src in COMBINATIONS:
            t0 = time.process_time()
            pred = invert_observations(
                obs, load_model(str(models[flow_src] / f"flow_delta{tag}.pt")),
                load_model(str(models[ed_src] / f"encoder_decoder_delta{tag}.pt")),
                load_model(str(models[ed_src] / "emulator.pt")), n_latent=int(study["n_latent"]),
                n_flow_samples=int(study["n_flow_samples"]), seed=seed, reference_outputs=y_ref,
                n_reference=int(study["n_reference"]), reference_flow_samples=int(study["reference_flow_samples"]),
                corrector_steps=int(study["corrector_steps"]))
            cpu = time.process_time() - t0
            ratio, each = ek_ratio(error_per_output(patients, pred), delta)
            rows.append({"delta": delta, "flow": flow_src, "encoder_decoder + emulator": ed_src,
                         "e_k / paper": ratio, "cpu_seconds": cpu})
            per_output.append({"delta": delta, "flow": flow_src, "encoder_decoder + emulator": ed_src, **each})
            print(rows[-1], flush=True)
    table, each = pd.DataFrame(rows), pd.DataFrame(per_output)
    print(table.to_string(index=False, float_format="%.4g"))
    run.save("ehr_network_swap", "EHR inversion: our networks and the published ones, swapped",
             f"The workflow's EHR inversion of its selected patients (Algorithm 1 with "
             f"{int(study['n_flow_samples']):,} flow samples, {int(study['n_latent'])} latent draws, "
             f"{int(study['corrector_steps'])} predictor-corrector rounds, seed {seed}) at noise levels "
             f"{', '.join(f'{d:g}' for d in args.deltas)}, with the flow and the encoder/decoder (with the "
             f"emulator it was trained through) each taken from our trained networks or the published ones. "
             f"e_k / paper: geometric mean over the outputs seen in more than 10 patients of table 5's e_k over "
             f"the paper's. One thread.",
             [results_io.table(table, "swap", "Per noise level and combination: e_k / paper and CPU seconds.",
                               FORMATS),
              results_io.table(each, "per_output", "Per output: e_k / paper.", page=False)],
             parameters={"run": results_io.portable(str(args.run.resolve())), "deltas": args.deltas,
                         "ehr_study": study, "seed": seed},
             note=args.note)
    return table


if __name__ == "__main__":
    main()
