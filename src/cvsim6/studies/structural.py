"""Structural identifiability study (paper section 3.3, appendix C), as workflow steps.

All parameter sets decoded by NN_d are checked through the *simulator* (batch path),
not the emulator. Units: registry units throughout. These steps write data only (tables,
JSON, CSV); :mod:`cvsim6.reporting.structural_figures` draws the figures from those files.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from cvsim6.data import datasets
from cvsim6.studies import evaluation
from cvsim6.model import identifiability
from cvsim6.inference import inversion
from cvsim6 import paper_values
from cvsim6.data import priors
from cvsim6.model import solver
from cvsim6.model.equations import outside_domain
from cvsim6.nets import DEFAULT_CORRECTOR_STEPS, load_model
from cvsim6.registry import OUTPUT_NAMES, PARAMETER_NAMES
from cvsim6.table_files import write_table

log = logging.getLogger(__name__)


def _simulate(v: np.ndarray, simulator: dict) -> tuple[np.ndarray, np.ndarray]:
    """Decoded parameter sets through the batch simulator; sets outside the model's domain
    (a decoder can extrapolate, e.g. a negative compliance) get status 7, not an error."""
    return solver.simulate_batch(v, steps_per_cycle=simulator["steps_per_cycle"],
                                 n_cycles=simulator["n_cycles"], window_cycles=simulator["window_cycles"],
                                 invalid="flag")


def _flag_counts(status: np.ndarray) -> dict[str, int]:
    """Decoded sets outside the model's domain, unphysical ones (simulated, left out) and the
    others the simulator flagged (solver status codes)."""
    special = (solver.STATUS_OUTSIDE_DOMAIN, solver.STATUS_UNPHYSICAL)
    return {"outside_domain": int((status == solver.STATUS_OUTSIDE_DOMAIN).sum()),
            "unphysical": int((status == solver.STATUS_UNPHYSICAL).sum()),
            "flagged": int(((status != 0) & ~np.isin(status, special)).sum())}


def _flag_words(status: np.ndarray) -> str:
    c = _flag_counts(status)
    return (f"{c['outside_domain']} decoded sets outside the model's domain, {c['unphysical']} unphysical, "
            f"{c['flagged']} flagged by the simulator")


def _manifold_samples(samples: str) -> tuple[np.ndarray, int]:
    """Decoded manifold samples inside the model's domain (N, 23), and how many were not."""
    v = datasets.read_dataset(samples)[list(PARAMETER_NAMES)].to_numpy()
    bad = outside_domain(v)
    return v[~bad], int(bad.sum())


def inversion_table(encoder_decoder: str, validation: str, csv: str, summary: str, md: str, simulator: dict, seed: int,
                    corrector_steps: int = DEFAULT_CORRECTOR_STEPS) -> None:
    """Table 3: decoder on the validation outputs (one w each, ``corrector_steps`` rounds of
    predictor-corrector sampling), pushed through the simulator."""
    ed = load_model(encoder_decoder)
    _, y = datasets.load_split(validation)
    v = inversion.decode_latent(ed, y, 1, seed=seed, corrector_steps=corrector_steps)[:, 0]
    yhat, st = _simulate(v, simulator)
    ok = st == 0
    stats = evaluation.error_statistics(y[ok], yhat[ok])
    write_table(evaluation.error_table(stats, paper_values.INVERSION_STRUCTURAL), csv, md,
                caption=f"Absolute reconstruction error of the amortized inversion on {ok.sum():,} of "
                        f"{len(y):,} validation outputs (decoded parameters simulated; {_flag_words(st)}"
                        f"{evaluation.nonfinite_words(stats)}); "
                        "paper table 3 beside")
    Path(summary).write_text(json.dumps({"n": int(len(y)), **_flag_counts(st)}, indent=2) + "\n")


def choose_observation(flow: str, csv: str, md: str, source: str, n_flow_samples: int, seed: int) -> None:
    """y*: the paper's table values, or the highest-density of ``n_flow_samples`` NN_f samples."""
    if source == "paper":
        y = np.array(paper_values.Y_STAR)
    else:
        import torch

        f = load_model(flow)
        samples = f.sample_physical(n_flow_samples, generator=torch.Generator().manual_seed(seed))
        lp = f.log_prob_physical(samples)
        y = samples[int(np.nanargmax(lp))]
    df = pd.DataFrame({"Output": list(OUTPUT_NAMES), "y*": y, "paper y*": paper_values.Y_STAR})
    write_table(df, csv, md, caption=f"The observation y* (source: {source})")


def _y_star(observation: str) -> np.ndarray:
    return pd.read_csv(observation)["y*"].to_numpy(float)


def sample_manifold(encoder_decoder: str, observation: str, samples: str, n_samples: int, seed: int,
                    corrector_steps: int = DEFAULT_CORRECTOR_STEPS) -> None:
    """Decode y* with ``n_samples`` latent draws (``corrector_steps`` predictor-corrector
    rounds): parameter sets on the manifold M_y* (Parquet)."""
    v = inversion.decode_latent(load_model(encoder_decoder), _y_star(observation)[None], n_samples, seed=seed,
                                corrector_steps=corrector_steps)[0]
    datasets.write_dataset(pd.DataFrame(v, columns=list(PARAMETER_NAMES)), samples)


#: The traced quantities of the trajectory figures: column -> (solver array, compartment index);
#: pressures in mmHg (``P``), the left-ventricular volume in mL (``V``).
TRACED = {"P_a": ("P", 1), "P_r": ("P", 3), "P_pa": ("P", 4), "V_l": ("V", 0)}


def last_cycle_traces(params: np.ndarray, simulator: dict) -> pd.DataFrame:
    """P_a, P_r, P_pa (mmHg) and V_l (mL) over the last cycle of each parameter set (N, 23),
    simulated one by one (batch path), against ``t_over_T`` (time since the cycle's start / T,
    T = 60 / Hr s). Column ``set`` is the row of ``params``; sets outside the model's domain
    are left out."""
    frames = []
    for i, p in enumerate(np.asarray(params, float)):
        if outside_domain(p)[0]:
            continue
        traj, _, _ = solver.simulate_trajectory(p, steps_per_cycle=simulator["steps_per_cycle"],
                                                n_cycles=simulator["n_cycles"],
                                                window_cycles=simulator["window_cycles"])
        T = 60.0 / p[0]
        m = traj.t >= traj.t[-1] - T
        columns = {"set": i, "t_over_T": (traj.t[m] - traj.t[m][0]) / T}
        for name, (array, k) in TRACED.items():
            columns[name] = getattr(traj, array)[m, k]
        frames.append(pd.DataFrame(columns))
    if not frames:
        return pd.DataFrame(columns=["set", "t_over_T", *TRACED])
    return pd.concat(frames, ignore_index=True)


def reconstruction_error_sources(y_star: np.ndarray, y_sim: np.ndarray, y_emulated: np.ndarray) -> dict[str, float]:
    """Split the reconstruction error of decoded sets v into its two sources.

    ``y_sim`` = f(v) from the simulator, ``y_emulated`` = NN_e(v) from the emulator, both
    (n, 16) in physical units. ``decoder``: ||NN_e(v) - y*|| / ||y*||, how far the decoded sets
    miss y* as the networks see it (the encoder/decoder's consistency, what training can
    reach); ``emulator``: ||NN_e(v) - f(v)|| / ||f(v)||, the emulator's own error at those
    sets. The simulator's error ||f(v) - y*|| / ||y*|| is at most the sum of the two (triangle
    inequality, up to the ratio of the norms). Max and median of each, fractions.
    """
    decoder = evaluation.relative_l2_errors(np.broadcast_to(y_star, y_emulated.shape), y_emulated)
    emulator = evaluation.relative_l2_errors(y_sim, y_emulated)
    return {"max_rel_l2_error_decoder": float(decoder.max()), "median_rel_l2_error_decoder": float(np.median(decoder)),
            "max_rel_l2_error_emulator": float(emulator.max()),
            "median_rel_l2_error_emulator": float(np.median(emulator))}


def _max_spread(y_star: np.ndarray, yhat: np.ndarray, status: np.ndarray, subset: int, resamples: int,
                seed: int) -> dict:
    """How the max relative l2 error over ``subset`` draws depends on the draws: its 10/50/90%
    quantiles over ``resamples`` random ``subset``-subsets of the simulated sets (fractions)."""
    ok = status == 0
    l2 = evaluation.relative_l2_errors(np.broadcast_to(y_star, yhat[ok].shape), yhat[ok])
    maxes = evaluation.max_of_random_subsets(l2, subset, resamples, seed)
    q10, q50, q90 = (float(x) for x in np.percentile(maxes, [10, 50, 90]))
    return {"n_simulated": int(len(status)), **_flag_counts(status), "subset": int(subset),
            "resamples": int(resamples), "q10": q10, "q50": q50, "q90": q90,
            "median_rel_l2_error": float(np.median(l2))}


def manifold_reconstruction(samples: str, observation: str, csv: str, summary: str, md: str, traces: str,
                            simulator: dict, n_reconstruct: int, n_traces: int, emulator: str | None = None,
                            n_spread: int = 0, spread_resamples: int = 2000, seed: int = 0) -> None:
    """The first ``n_reconstruct`` manifold samples through the simulator: max relative error
    against y* (paper: ~0.139%), and the last-cycle ``traces`` (CSV, :func:`last_cycle_traces`)
    of the first ``n_traces`` of them for the trajectory figure.

    With ``emulator`` (the study's NN_e) the summary also splits the error into the decoder's
    and the emulator's share (:func:`reconstruction_error_sources`). With ``n_spread`` >
    ``n_reconstruct`` the first ``n_spread`` samples are simulated (the headline still uses the
    first ``n_reconstruct``, the same numbers: a set's simulation does not depend on the others)
    and the summary's ``max_rel_l2_error_resampled`` gives how that max depends on which draws
    were taken: its 10/50/90% quantiles over ``spread_resamples`` random ``n_reconstruct``-subsets
    of them (:func:`cvsim6.studies.evaluation.max_of_random_subsets`, seeded by ``seed``), beside their
    median error.
    """
    v_all = datasets.read_dataset(samples)[list(PARAMETER_NAMES)].to_numpy()
    v = v_all[:n_reconstruct]
    y_star = _y_star(observation)
    spread = int(n_spread) > len(v)
    yhat_all, st_all = _simulate(v_all[:int(n_spread)] if spread else v, simulator)
    yhat, st = yhat_all[:len(v)], st_all[:len(v)]
    if not (st == 0).any():
        raise ValueError(f"{samples}: none of the {len(v)} decoded sets simulated ({_flag_words(st)})")
    ok = st == 0
    rel = np.abs(yhat[ok] - y_star) / np.abs(y_star)
    worst = rel.max(axis=0)
    l2 = evaluation.relative_l2_errors(np.broadcast_to(y_star, yhat[ok].shape), yhat[ok])
    df = pd.DataFrame({"Output": list(OUTPUT_NAMES), "max relative error": worst})
    info = {"n": int(len(v)), **_flag_counts(st), "max_rel_l2_error": float(l2.max()),
            "median_rel_l2_error": float(np.median(l2)),
            "paper_max_rel_l2_error": paper_values.STRUCTURAL_HEADLINES["max_rel_error_manifold"],
            "max_rel_error_per_output": float(worst.max()), "worst_output": OUTPUT_NAMES[int(np.argmax(worst))]}
    sources = ""
    if spread:
        r = info["max_rel_l2_error_resampled"] = _max_spread(y_star, yhat_all, st_all, len(v), spread_resamples, seed)
        sources = (f"; the max over {len(v)} draws, for {spread_resamples:,} random sets of {len(v)} of the first "
                   f"{r['n_simulated']:,} draws: 10/50/90% quantiles {r['q10']:.3%} / {r['q50']:.3%} / "
                   f"{r['q90']:.3%} (their median error {r['median_rel_l2_error']:.3%})")
    if emulator is not None:
        info.update(reconstruction_error_sources(y_star, yhat[ok], load_model(emulator).predict(v[ok])))
        sources += (f"; of which the decoder, ||NN_e(v) - y*|| / ||y*||: max {info['max_rel_l2_error_decoder']:.3%}, "
                    f"median {info['median_rel_l2_error_decoder']:.3%}, and the emulator at these sets, "
                    f"||NN_e(v) - f(v)|| / ||f(v)||: max {info['max_rel_l2_error_emulator']:.3%}")
    write_table(df, csv, md, caption=f"{int(ok.sum())} of {len(v)} decoded parameter sets for y* simulated "
                                     f"({_flag_words(st)}): largest relative l2 error ||f(v) - y*|| / ||y*|| "
                                     f"{info['max_rel_l2_error']:.3%}, median {info['median_rel_l2_error']:.3%} "
                                     f"(the paper's measure: about 0.139%){sources}; below, the largest relative "
                                     "error of each output")
    Path(summary).write_text(json.dumps(info, indent=2) + "\n")
    last_cycle_traces(v[:n_traces], simulator).to_csv(traces, index=False)


def parallel_coordinates_data(samples: str, lines: str, summary: str, prior: dict, n_lines: int) -> None:
    """What the parallel-coordinate figure draws: the first ``n_lines`` manifold samples inside
    the model's domain (``lines`` CSV, one column per parameter, registry units) and, in
    ``summary`` (JSON), each axis' limits (the prior bounds widened by 5% of their width on both
    sides, registry units) and how many of all the samples lie outside the model's domain."""
    v, n_out = _manifold_samples(samples)
    v = v[:n_lines]
    lo, hi = priors.prior_bounds(prior)
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    pd.DataFrame(v, columns=list(PARAMETER_NAMES)).to_csv(lines, index=False)
    Path(summary).write_text(json.dumps(
        {"lines": int(len(v)), "outside_domain": n_out,
         "axis_limits": {name: [float(a), float(b)] for name, a, b in zip(PARAMETER_NAMES, lo, hi)}},
        indent=2) + "\n")


def manifold_svd_modes(samples: str, csv: str, summary: str, level: float = 0.99) -> None:
    """Singular values and cumulative energy of the manifold samples (``csv``), and the modes
    reaching ``level`` of the energy beside the paper's (``summary`` JSON)."""
    v, n_out = _manifold_samples(samples)
    s = identifiability.manifold_svd(v)
    ce = identifiability.cumulative_energy(s)
    n, e = identifiability.modes_for_energy(s, level)
    pd.DataFrame({"mode": np.arange(1, len(s) + 1), "singular_value": s,
                  "cumulative_energy": ce}).to_csv(csv, index=False)
    paper = paper_values.STRUCTURAL_HEADLINES
    Path(summary).write_text(json.dumps(
        {"n_samples": int(len(v)), "outside_domain": n_out, "level": level, "modes": n, "energy": e,
         "paper_modes": paper["modes_99"], "paper_energy": paper["energy_at_modes"]}, indent=2) + "\n")


def missing_data(flow: str, encoder_decoder: str, observation: str, csv: str, summary: str, md: str, traces: str,
                 simulator: dict, missing: list, n_flow_samples: int, top_k: int, n_latent: int, seed: int,
                 corrector_steps: int = DEFAULT_CORRECTOR_STEPS) -> None:
    """Algorithm 1 on y* without ``missing``: top-k completions x n_latent draws, simulated;
    largest relative l2 error on the observed entries (paper: ~0.408%), and the last-cycle
    ``traces`` (CSV) of every decoded set: :func:`last_cycle_traces` with ``completion`` (its
    rank, from 1) and ``set`` (the latent draw)."""
    y_star = _y_star(observation)
    y_obs = y_star.copy()
    miss = np.array([n in missing for n in OUTPUT_NAMES])
    y_obs[miss] = np.nan
    best, lp = inversion.complete_missing(load_model(flow), y_obs, n_flow_samples, top_k=top_k, seed=seed)
    v = inversion.decode_latent(load_model(encoder_decoder), best, n_latent, seed=seed,
                                corrector_steps=corrector_steps)  # (k, n, 23)
    yhat, st = _simulate(v.reshape(-1, len(PARAMETER_NAMES)), simulator)
    if not (st == 0).any():
        raise ValueError(f"none of the {len(st)} decoded completions simulated ({_flag_words(st)})")
    y_obs_part = np.broadcast_to(y_star[~miss], yhat[st == 0][:, ~miss].shape)
    l2 = evaluation.relative_l2_errors(y_obs_part, yhat[st == 0][:, ~miss])
    table = pd.DataFrame(best, columns=list(OUTPUT_NAMES))
    table.insert(0, "log_density", lp)
    table.insert(0, "rank", np.arange(1, top_k + 1))
    write_table(table, csv, md, caption=f"Top {top_k} completions of y* without {', '.join(missing)} "
                                        f"({n_flow_samples:,} flow samples); the {top_k}x{n_latent} decoded sets "
                                        f"simulated ({_flag_words(st)}): largest relative l2 error over "
                                        f"the observed entries {l2.max():.3%} (paper: about 0.408%)")
    Path(summary).write_text(json.dumps(
        {"max_rel_l2_error_observed": float(l2.max()), **_flag_counts(st),
         "paper": paper_values.STRUCTURAL_HEADLINES["max_rel_error_missing"]}, indent=2) + "\n")
    per_completion = [last_cycle_traces(v[g], simulator) for g in range(top_k)]
    for g, frame in enumerate(per_completion):
        frame.insert(0, "completion", g + 1)
    pd.concat(per_completion, ignore_index=True).to_csv(traces, index=False)


def jacobian_check(samples: str, csv: str, summary: str, md: str, spectra: str, prior: dict, simulator: dict,
                   n_points: int, rel_step: float, rank_rtol: float) -> None:
    """Local identifiability at manifold samples: scaled Jacobian spectra (``spectra`` CSV, one
    row per point, columns sigma_1 >= sigma_2 >= ..., dimensionless), ranks, and per parameter
    the spread over the manifold (fraction of the prior width) and null-space share."""
    v_all, _ = _manifold_samples(samples)
    v = v_all[:n_points]
    lo, hi = priors.prior_bounds(prior)
    w = hi - lo
    f = identifiability.simulator_outputs(simulator["steps_per_cycle"])
    J = identifiability.finite_difference_jacobian(f, v, w, rel_step=rel_step)
    ok = np.isfinite(J).all(axis=(1, 2))
    sv, ranks, shares = identifiability.local_identifiability(identifiability.scaled_jacobian(J[ok], w), rank_rtol)
    spread = (np.percentile(v_all, 97.5, axis=0) - np.percentile(v_all, 2.5, axis=0)) / w
    df = pd.DataFrame({"Parameter": list(PARAMETER_NAMES), "manifold spread / prior width (95%)": spread,
                       "null-space share (mean)": shares.mean(axis=0),
                       "null-space share (max)": shares.max(axis=0)})
    df = df.sort_values("null-space share (mean)", ascending=False)
    rank_counts = {int(r): int(c) for r, c in zip(*np.unique(ranks, return_counts=True))}
    write_table(df, csv, md, caption=f"Local identifiability at {ok.sum()} manifold samples: Jacobian rank "
                                     f"{rank_counts} (rtol {rank_rtol:g}), so a local manifold dimension of "
                                     f"{23 - int(np.median(ranks))}; the SVD of the manifold samples needs "
                                     "its own count of modes (see manifold_svd.json)")
    Path(summary).write_text(json.dumps(
        {"points": int(ok.sum()), "rank_counts": rank_counts, "median_rank": float(np.median(ranks)),
         "local_manifold_dimension": 23 - int(np.median(ranks))}, indent=2) + "\n")
    pd.DataFrame(sv, columns=[f"sigma_{k}" for k in range(1, sv.shape[1] + 1)]).to_csv(spectra, index=False)
