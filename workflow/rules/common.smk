# Helpers shared by the workflow: output locations and the package code
# each step depends on. Only constants and functions here, no rules.

#: Everything the workflow produces (git-ignored except results/README.md).
RESULTS = "results"
#: Tables of the paper (CSV + Markdown).
TABLES = f"{RESULTS}/tables"
#: Per-rule log files.
LOGS = "logs"
#: Per-rule benchmark TSV files (wall time, memory).
BENCHMARKS = "benchmarks"
#: The installed package whose functions the rules call.
PACKAGE_DIR = "src/cvsim6"


def package_code(*modules):
    """Source files of the given cvsim6 modules, e.g. ``package_code("tables")``.

    Rules declare them as the input named ``code`` so that a change of the code
    that produces an output marks that output for rerun (Snakemake's default
    rerun triggers include input modification times). call.py does not pass
    ``code`` to the function.
    """
    return [f"{PACKAGE_DIR}/{module}.py" for module in modules]


def ehr_csv(wildcards=None):
    """The EHR CSV: config ehr_data.path if set, else the copy downloaded into resources/."""
    return config["ehr_data"]["path"] or "resources/EHR_dataset.csv"


def noise_tag(delta):
    """File-name tag of a training-noise level, e.g. 0.5 -> '0.5', 1.0 -> '1'."""
    return f"{float(delta):g}"


def training_targets(study):
    """Every trained model, loss curve and table of ``study`` for the config in use."""
    deltas = [noise_tag(d) for d in config["training"]["studies"][study]["noise_levels"]]
    return (
        [f"{MODELS}/{study}/emulator.pt", f"{TRAINING}/{study}/emulator_losses.png",
         f"{TABLES}/{study}_emulator_validation.md", f"{TABLES}/{study}_architectures.md",
         f"{TABLES}/{study}_schedules.md", f"{TRAINING}/{study}/emulator_l2_errors.png"]
        + [f"{TRAINING}/{study}/flow_delta{d}_marginals.png" for d in deltas]
        + [f"{MODELS}/{study}/{stage}_delta{d}.pt" for d in deltas for stage in ("flow", "encoder_decoder")]
        + [f"{TRAINING}/{study}/{stage}_delta{d}_losses.png" for d in deltas for stage in ("flow", "encoder_decoder")]
    )
