"""Where the scorecard's headlines are read from: the workflow outputs of one network source,
as paths under the results root. The one home of that layout: the workflow (common.smk loads
this file without importing the package, so it imports nothing), the scorecards, the
benchmarks and the tests read it."""

#: Headline files shared by every network source (the stiffness analysis), under the results root.
SHARED = {"stiffness": "stiffness/sr_extremes.csv"}
#: Headline files of one network source, under its root (results/, results/published/ or
#: results/seeds/<seed>/).
PER_NETWORKS = {
    "structural_emulator": "tables/structural_emulator_validation.csv",
    "structural_inversion": "tables/structural_inversion_errors.csv",
    "manifold": "tables/structural_manifold_reconstruction.json",
    "svd": "structural/manifold_svd.json",
    "missing": "tables/structural_missing_data.json",
    "ehr_emulator": "training/ehr/emulator_l2_errors.json",
    "ehr_errors": "tables/ehr_error_per_output.csv",
}
#: The keys of a source's headline files, in scorecard order.
HEADLINE_FILES = (*SHARED, *PER_NETWORKS)


def headline_files(results: str, root: str) -> dict[str, str]:
    """The headline files of the networks whose results lie under ``root``, the shared ones under
    ``results`` (both folder paths, without a trailing slash)."""
    return {**{k: f"{results}/{p}" for k, p in SHARED.items()},
            **{k: f"{root}/{p}" for k, p in PER_NETWORKS.items()}}
