"""Error statistics on known numbers, and the structural study end to end (smoke config)."""
import json

import numpy as np
import pandas as pd
import pytest

from cvsim6 import datasets, evaluation, paper_values, registry, structural_study
from cvsim6.model import outside_domain
from test_workflow import copy_workflow, snakemake


def test_error_statistics_known_values():
    y = np.zeros((4, 16))
    yhat = np.zeros((4, 16))
    yhat[:, 0] = [1.0, -1.0, 3.0, -3.0]  # |err| 1, 1, 3, 3: mean 2, max 3, std 1
    yhat[2, 5] = np.nan  # a row with a NaN is left out everywhere
    s = evaluation.error_statistics(y, yhat)
    assert s.loc["Hr"].tolist() == pytest.approx([5 / 3, 3.0, np.std([1, 1, 3])])
    assert (s.loc["P_a_sys"] == 0).all()
    t = evaluation.error_table(s, {"mean": list(range(16)), "max": [0] * 16, "std": [0] * 16})
    assert list(t["Output"]) == list(registry.OUTPUT_NAMES) and t.loc[3, "Mean (paper)"] == 3


def test_relative_l2_errors():
    y = np.array([[3.0, 4.0] + [0.0] * 14, [1.0] + [0.0] * 15])
    yhat = y.copy()
    yhat[0, 0] += 0.5  # 0.5 / 5
    np.testing.assert_allclose(evaluation.relative_l2_errors(y, yhat), [0.1, 0.0])


def test_out_of_domain_decoded_sets_are_counted_not_fatal(tmp_path):
    """A decoder may extrapolate past the model's domain (C_v < 0 seen in a real run): such sets
    are counted and left out; the others give the known answer (y* from the same parameters)."""
    from cvsim6 import datasets, solver

    sim = {"steps_per_cycle": solver.DEFAULT_STEPS_PER_CYCLE, "n_cycles": solver.DEFAULT_N_CYCLES,
           "window_cycles": solver.DEFAULT_WINDOW_CYCLES}
    v = np.repeat(registry.default_parameters()[None], 4, axis=0)
    v[1, registry.PARAMETER_INDEX["C_v"]] = -41.6
    v[3, registry.PARAMETER_INDEX["V0_v"]] *= 1.01  # a different, valid set
    y_star, st = solver.simulate_batch(v[:1])
    obs = tmp_path / "obs.csv"
    pd.DataFrame({"Output": list(registry.OUTPUT_NAMES), "y*": y_star[0]}).to_csv(obs, index=False)
    samples = tmp_path / "samples.parquet"
    datasets.write_dataset(pd.DataFrame(v, columns=list(registry.PARAMETER_NAMES)), samples)
    csv = tmp_path / "rec.csv"
    structural_study.manifold_reconstruction(str(samples), str(obs), csv=str(csv), summary=str(tmp_path / "rec.json"),
                                             md=str(tmp_path / "rec.md"), figure=str(tmp_path / "rec.png"),
                                             simulator=sim, n_reconstruct=3, n_traces=3)
    summary = json.loads((tmp_path / "rec.json").read_text())
    assert summary["outside_domain"] == 1 and summary["flagged"] == 0
    assert summary["max_rel_l2_error"] < 1e-12 and summary["max_rel_error_per_output"] < 1e-12  # rows 0 and 2 are y*'s own parameters
    structural_study.manifold_svd_figure(str(samples), str(tmp_path / "svd.png"), str(tmp_path / "svd.csv"),
                                         str(tmp_path / "svd.json"))
    svd = json.loads((tmp_path / "svd.json").read_text())
    assert svd["n_samples"] == 3 and svd["outside_domain"] == 1


def test_trajectory_panels_draw_every_set_and_target():
    """Each of the 4 panels gets one curve per parameter set and a dashed line per observed
    target, also when handed ``axes.flat`` (an iterator)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsim6 import solver

    sim = {"steps_per_cycle": 200, "n_cycles": 6, "window_cycles": 2}
    v = np.repeat(registry.default_parameters()[None], 3, axis=0)
    v[1, registry.PARAMETER_INDEX["C_a"]] *= 1.2
    v[2, registry.PARAMETER_INDEX["C_v"]] = -1.0  # outside the domain: skipped
    y_star = solver.simulate_batch(v[:1])[0][0]
    observed = np.ones(16, bool)
    observed[registry.OUTPUT_INDEX["P_a_dia"]] = False
    fig, axes = plt.subplots(2, 2)
    structural_study._trajectory_panels(axes.flat, v, y_star, sim, ["r", "g", "b"], observed=observed)
    dashed = [sum(ln.get_linestyle() == "--" for ln in ax.lines) for ax in axes.flat]
    curves = [sum(ln.get_linestyle() == "-" for ln in ax.lines) for ax in axes.flat]
    assert curves == [2, 2, 2, 2] and dashed == [1, 2, 2, 2]
    assert [ax.get_ylabel() for ax in axes.flat] == ["P_a (mmHg)", "P_r (mmHg)", "P_pa (mmHg)", "V_l (mL)"]
    plt.close(fig)


@pytest.mark.slow
def test_structural_stage_end_to_end(tmp_path):
    work = copy_workflow(tmp_path)
    targets = ["results/tables/structural_inversion_errors.md", "results/structural/manifold_trajectories.png",
               "results/structural/manifold_parallel_coordinates.png", "results/structural/manifold_svd.png",
               "results/structural/missing_data_trajectories.png", "results/structural/jacobian_spectra.png"]
    proc = snakemake("--cores", "2", *targets, "--configfile", "config/smoke.yaml", cwd=work)
    assert proc.returncode == 0, proc.stderr[-3000:]
    t = pd.read_csv(work / "results/tables/structural_inversion_errors.csv")
    assert len(t) == 16 and (t["Max (ours)"] >= t["Mean (ours)"]).all() and "Mean (paper)" in t
    obs = pd.read_csv(work / "results/tables/structural_observation.csv")
    np.testing.assert_allclose(obs["y*"], paper_values.Y_STAR)
    svd = json.loads((work / "results/structural/manifold_svd.json").read_text())
    sv = pd.read_csv(work / "results/structural/manifold_svd.csv")["singular_value"]
    # standardized columns: the squared singular values add up to n_samples per varying column
    v = datasets.read_dataset(work / "results/structural/manifold_samples.parquet")[list(registry.PARAMETER_NAMES)]
    v = v.to_numpy()[~outside_domain(v.to_numpy())]
    assert len(v) == svd["n_samples"]
    assert (sv**2).sum() == pytest.approx(len(v) * (v.std(axis=0) > 0).sum(), rel=1e-6)
    assert svd["n_samples"] + svd["outside_domain"] == 200
    miss = pd.read_csv(work / "results/tables/structural_missing_data.csv")
    assert len(miss) == 4 and (np.diff(miss["log_density"]) <= 0).all()
    for name in registry.OUTPUT_NAMES:  # observed entries of y* are kept in every completion
        if name not in paper_values.MISSING_OUTPUTS:
            assert (miss[name] == obs.set_index("Output").loc[name, "y*"]).all()
    jac = json.loads((work / "results/tables/structural_local_identifiability.json").read_text())
    # V0_a, V0_v, V0_r, V0_pa, V0_pv set the outputs only through their sum: 4 exact null
    # directions at every point, in which V0_a holds at least 1 - w_a^2 / sum w^2 = 0.93
    shares = pd.read_csv(work / "results/tables/structural_local_identifiability.csv").set_index("Parameter")
    assert shares.loc["V0_a", "null-space share (mean)"] * jac["local_manifold_dimension"] > 0.9
    assert shares.loc["Hr", "null-space share (max)"] < 1e-6  # observed directly
    for fig in targets[1:]:
        assert (work / fig).with_suffix(".pdf").is_file()
