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
