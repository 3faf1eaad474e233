"""Training data: seeding, sharding, failures, splits, file format."""
import json

import numpy as np
import pandas as pd
import pytest

from cvsim6.data import datasets
from cvsim6 import registry
from cvsim6.data.datasets import DataError

PRIOR = {"default": [0.7, 1.3], "kinds": {"compliance": [0.5, 1.5]}}
SIM = {"steps_per_cycle": 400, "n_cycles": 12, "window_cycles": 3, "method": "batch"}
SPLIT = {"validation": 10, "train_fraction": 0.75}


def build(tmp, n_shards, n=80, seed=3, max_fail=0.5, edit=None):
    """Run the three data steps as the workflow does, with ``n_shards`` shards."""
    tmp.mkdir(parents=True, exist_ok=True)
    shards = [str(tmp / f"p{i}.parquet") for i in range(n_shards)]
    datasets.sample_prior(str(tmp / "params.parquet"), PRIOR, n, seed, "structural", shards=shards)
    if edit is not None:
        edit(shards)
    sims = []
    for i, sp in enumerate(shards):
        out = str(tmp / f"s{i}.parquet")
        datasets.simulate_shard(sp, out, SIM, shard=f"{i + 1}-of-{n_shards}")
        sims.append(out)
    paths = {k: str(tmp / f"{k}.parquet") for k in datasets.SPLITS}
    datasets.gather_study(sims, **paths, failures=str(tmp / "failures.csv"), manifest=str(tmp / "manifest.json"),
                          study="structural", split=SPLIT, max_failure_fraction=max_fail, prior=PRIOR,
                          seed=seed, simulator=SIM)
    return {k: datasets.read_dataset(v) for k, v in paths.items()}


def test_paper_split_sizes():
    assert datasets.split_sizes(54000, 4000, 0.75) == {"train": 37500, "test": 12500, "validation": 4000}
    with pytest.raises(DataError, match="validation = 50"):
        datasets.split_sizes(50, 50, 0.75)


def test_datasets_identical_for_1_and_4_shards(tmp_path):
    one = build(tmp_path / "one", 1)
    four = build(tmp_path / "four", 4)
    for k in datasets.SPLITS:
        pd.testing.assert_frame_equal(one[k], four[k], check_exact=True)
    sizes = {k: len(v) for k, v in one.items()}
    assert sizes == {"train": 52, "test": 18, "validation": 10}
    # rows keep their sample order: train, then test, then validation
    order = np.concatenate([one[k]["sample"].to_numpy() for k in datasets.SPLITS])
    assert (order == np.arange(80)).all()
    # a different master seed gives different data
    other = build(tmp_path / "other", 2, seed=4)
    assert not np.allclose(other["train"]["C_a"].to_numpy(), one["train"]["C_a"].to_numpy())


def test_samples_lie_in_the_prior(tmp_path):
    datasets.sample_prior(str(tmp_path / "p.parquet"), PRIOR, 500, 1, "structural")
    df = datasets.read_dataset(tmp_path / "p.parquet")
    ca = df["C_a"] / registry.PARAMETER_BY_NAME["C_a"].default
    ra = df["R_a"] / registry.PARAMETER_BY_NAME["R_a"].default
    assert ca.between(0.5, 1.5).all() and ca.min() < 0.55 and ca.max() > 1.45
    assert ra.between(0.7, 1.3).all()
    assert df["P_th"].between(-5.2, -2.8).all()


def _poison(shards):
    """Unstressed volumes above the blood volume in sample 7: a flagged row."""
    df = datasets.read_dataset(shards[0])
    df.loc[df["sample"] == 7, "V0_v"] = 6000.0
    datasets.write_dataset(df, shards[0])


def test_flagged_row_goes_to_failures_not_splits(tmp_path):
    splits = build(tmp_path, 2, edit=_poison)
    fails = pd.read_csv(tmp_path / "failures.csv")
    assert list(fails["sample"]) == [7]
    assert fails.loc[0, "status"] == "negative compartment volume"
    assert fails.loc[0, "V0_v"] == 6000.0
    for df in splits.values():
        assert 7 not in set(df["sample"])
        assert "status" not in df
    assert sum(len(df) for df in splits.values()) == 79
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["n_failed"] == 1
    assert manifest["failures_by_reason"] == {"negative compartment volume": 1}
    assert manifest["split_sizes"] == {"train": 51, "test": 18, "validation": 10}
    assert manifest["prior_bounds"]["C_a"] == pytest.approx([0.8, 2.4])


def test_gather_fails_above_threshold_and_keeps_shards(tmp_path):
    with pytest.raises(DataError, match=r"1 of 80 simulated rows flagged .*max_failure_fraction"):
        build(tmp_path, 2, edit=_poison, max_fail=0.0)
    assert (tmp_path / "s0.parquet").is_file() and (tmp_path / "s1.parquet").is_file()
    assert list(pd.read_csv(tmp_path / "failures.csv")["sample"]) == [7]


def test_parquet_keeps_names_and_units(tmp_path):
    build(tmp_path, 1, n=30)
    units = datasets.dataset_units(tmp_path / "train.parquet")
    assert units["C_a"] == "mL/mmHg" and units["SVR"] == "dyn·s/cm^5" and units["Hr"] in ("bpm",)
    v, y = datasets.load_split(tmp_path / "train.parquet")
    assert v.shape[1] == 23 and y.shape[1] == 16


def test_scatteritem_parsing():
    assert datasets.parse_scatteritem("3-of-8") == (2, 8)
    with pytest.raises(ValueError, match="9-of-8"):
        datasets.parse_scatteritem("9-of-8")
    sizes = [datasets.shard_rows(54000, i, 7) for i in range(7)]
    assert sizes[0].start == 0 and sizes[-1].stop == 54000
    assert all(a.stop == b.start for a, b in zip(sizes, sizes[1:]))


@pytest.mark.slow
def test_shard_with_reference_method_matches_batch(tmp_path):
    """The shard step's reference route: 6 cycles (half the default) keep Radau's cost down; both
    methods solve the same initial value problem, so they agree however far it has settled."""
    sim = {**SIM, "n_cycles": 6, "window_cycles": 2}
    datasets.sample_prior(str(tmp_path / "p.parquet"), PRIOR, 2, 5, "structural")
    datasets.simulate_shard(str(tmp_path / "p.parquet"), str(tmp_path / "b.parquet"), sim)
    datasets.simulate_shard(str(tmp_path / "p.parquet"), str(tmp_path / "r.parquet"), {**sim, "method": "reference"})
    b = datasets.read_dataset(tmp_path / "b.parquet")
    r = datasets.read_dataset(tmp_path / "r.parquet")
    assert (b["status"] == "ok").all() and (r["status"] == "ok").all()
    np.testing.assert_allclose(b[list(registry.OUTPUT_NAMES)], r[list(registry.OUTPUT_NAMES)], rtol=2e-3, atol=0.05)
    assert not b[list(registry.OUTPUT_NAMES)].equals(r[list(registry.OUTPUT_NAMES)])


def test_load_split_reads_registry_order_and_names_a_damaged_cell(tmp_path):
    build(tmp_path, 1, n=30)
    df = datasets.read_dataset(tmp_path / "train.parquet")
    v, y = datasets.load_split(tmp_path / "train.parquet")
    np.testing.assert_array_equal(v[:, 0], df["Hr"].to_numpy())  # Hr: parameter 0 and output 0, one column
    np.testing.assert_array_equal(y[:, 0], df["Hr"].to_numpy())
    np.testing.assert_array_equal(y[:, -1], df["PVR"].to_numpy())
    df.loc[df.index[3], "C_v"] = np.nan
    datasets.write_dataset(df, tmp_path / "damaged.parquet")
    with pytest.raises(ValueError, match=r"damaged\.parquet: non-finite value in row 3, column 'C_v'"):
        datasets.load_split(tmp_path / "damaged.parquet")


def test_histogram_counts_are_numpy_histograms_of_all_splits(tmp_path):
    splits = build(tmp_path, 1, n=30)
    datasets.histogram_counts(*(str(tmp_path / f"{k}.parquet") for k in datasets.SPLITS),
                              counts=str(tmp_path / "histograms.csv"), bins=8)
    counts = pd.read_csv(tmp_path / "histograms.csv")
    assert list(counts.columns) == ["column", "bin", "left", "right", "count"]
    names = list(dict.fromkeys(registry.PARAMETER_NAMES + registry.OUTPUT_NAMES))
    assert list(counts["column"].unique()) == names  # Hr (parameter and output) once
    assert len(counts) == 8 * len(names) == 8 * 38
    every = pd.concat(splits.values(), ignore_index=True)
    for name in ("C_a", "LVEF", "Hr"):
        n, edges = np.histogram(every[name].to_numpy(), bins=8)
        rows = counts[counts["column"] == name]
        np.testing.assert_array_equal(rows["count"], n)
        np.testing.assert_array_equal(rows["left"], edges[:-1])  # read back to the last bit
        np.testing.assert_array_equal(rows["right"], edges[1:])
        assert rows["left"].iloc[0] == every[name].min() and rows["right"].iloc[-1] == every[name].max()
    assert (counts.groupby("column")["count"].sum() == 30).all()  # every set in every histogram


def test_histogram_figures_draw_the_counts(tmp_path, monkeypatch):
    """The data figures draw bars of the counts file alone (16 output panels, 23 input panels),
    and neither the figure module nor the datasets module imports the other side."""
    import subprocess
    import sys

    from cvsim6.reporting import data_figures
    from cvsim6.reporting.figures import label

    rows = [{"column": c, "bin": b, "left": 10.0 * b, "right": 10.0 * (b + 1), "count": (b + 1) * (i + 1)}
            for i, c in enumerate(dict.fromkeys(registry.PARAMETER_NAMES + registry.OUTPUT_NAMES)) for b in range(3)]
    pd.DataFrame(rows).to_csv(tmp_path / "histograms.csv", index=False)
    drawn = {}
    save = data_figures.save_figure
    monkeypatch.setattr(data_figures, "save_figure", lambda fig, path: (drawn.setdefault(path, fig), save(fig, path)))
    outputs, inputs = str(tmp_path / "outputs_histograms.png"), str(tmp_path / "inputs_histograms.png")
    data_figures.plot_histograms(str(tmp_path / "histograms.csv"), outputs, inputs, "toy")
    assert drawn[outputs].get_suptitle() == "toy study: outputs (6 sets)"  # Hr: 1 + 2 + 3
    panels = [ax for ax in drawn[outputs].axes if ax.get_visible()]
    assert [ax.get_xlabel() for ax in panels] == [label(n) for n in registry.OUTPUT_NAMES]
    lvef = panels[registry.OUTPUT_NAMES.index("LVEF")]
    i = list(dict.fromkeys(registry.PARAMETER_NAMES + registry.OUTPUT_NAMES)).index("LVEF")
    assert [p.get_height() for p in lvef.patches] == [1.0 * (i + 1), 2.0 * (i + 1), 3.0 * (i + 1)]
    assert [p.get_x() for p in lvef.patches] == [0.0, 10.0, 20.0]
    assert sum(ax.get_visible() for ax in drawn[inputs].axes) == 23
    assert (tmp_path / "outputs_histograms.pdf").is_file() and (tmp_path / "inputs_histograms.pdf").is_file()
    out = subprocess.run([sys.executable, "-c", "import sys, cvsim6.reporting.data_figures; "
                          "print(sorted(m for m in sys.modules if m in ('torch', 'cvsim6.model.solver', "
                          "'cvsim6.data.datasets', 'matplotlib.pyplot') or m.startswith('cvsim6.studies')))"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stderr
    out = subprocess.run([sys.executable, "-c", "import sys, cvsim6.data.datasets; print(sorted(m for m in "
                          "sys.modules if m.startswith('cvsim6.reporting') or m == 'matplotlib'))"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stderr
