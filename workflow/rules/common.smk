# Helpers shared by the workflow: output locations and the package code
# each step depends on. Only constants and functions here, no rules.

import importlib.util
from pathlib import Path

#: Everything the workflow produces (git-ignored except results/README.md).
RESULTS = "results"
#: Tables of the paper that do not depend on the networks (CSV + Markdown).
TABLES = f"{RESULTS}/tables"
#: Per-rule log files.
LOGS = "logs"
#: Per-job benchmark TSV files (wall and CPU time, memory), apart from the benchmark scripts.
BENCHMARKS = f"{LOGS}/benchmarks"
#: The installed package whose functions the rules call.
PACKAGE_DIR = "src/cvsim6"

#: Where target `seeds` puts the network results of each extra seed (results/seeds/<seed>/).
SEEDS_RESULTS = f"{RESULTS}/seeds"
#: Root of the networks this copy of the Snakefile trains: results/, or results/seeds/<seed>/ in
#: a seed module (seeds.smk), whose outputs Snakemake moves there but whose params it does not.
TRAINED_ROOT = (
    RESULTS
    if workflow.modifier.is_main_snakefile()
    else f"{SEEDS_RESULTS}/{config['seed']}"
)
#: The spread over seeds (target `seeds`), which the scorecard of `all` shows when it exists.
SEED_SCORECARD = f"{RESULTS}/report/seeds.csv"

#: Where the inVAErt networks come from: 'trained' by this workflow or 'published' (the paper's).
NETWORK_SOURCE = config["networks"]["source"]
#: Root of the results that depend on the networks, per source; the two never overwrite each other.
NETWORK_RESULTS = {"trained": RESULTS, "published": f"{RESULTS}/published"}
#: This run's root of network-dependent results, and its tables, logs and benchmarks.
NET = NETWORK_RESULTS[NETWORK_SOURCE]
NET_TABLES = f"{NET}/tables"
NET_LOGS = LOGS if NETWORK_SOURCE == "trained" else f"{LOGS}/published"
NET_BENCHMARKS = (
    BENCHMARKS if NETWORK_SOURCE == "trained" else f"{BENCHMARKS}/published"
)
#: Networks the downstream rules read: trained into results/models, converted into results/published/models.
MODELS = f"{NET}/models"

#: Report categories, one per part of the paper. The report lists them sorted by name,
#: hence the numbers: the scorecard first, then the paper's order, then what goes beyond it.
REPORT_SCORECARD = "1 Reproduction scorecard"
REPORT_MODEL = "2 CVSim-6 model (sec. 2.1, 3.2)"
REPORT_STIFFNESS = "3 Stiffness analysis (sec. 3.1)"
REPORT_STUDY = {
    "structural": "4 Structural identifiability (sec. 3.3, app. B-C)",
    "ehr": "5 EHR inversion (sec. 3.4, app. B)",
}
REPORT_BEYOND = "6 Beyond the paper"


def report_study(wildcards):
    """Report category of a result of one study, by its ``study`` wildcard."""
    return REPORT_STUDY[wildcards.study]


#: Appended to the report subcategory of a result of the networks in use when they are
#: the paper's published networks (networks.source: published).
NET_MARK = ", published networks" if NETWORK_SOURCE == "published" else ""


def load_package_file(module):
    """The package module ``module`` (a path under the package, without .py) loaded from its
    file: for the few that import nothing of the package, so that the workflow does not
    import the package itself."""
    spec = importlib.util.spec_from_file_location(
        f"cvsim6_{Path(module).name}", f"{PACKAGE_DIR}/{module}.py"
    )
    loaded = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loaded)
    return loaded


_codegraph = load_package_file("workflow/codegraph")
_headlines = load_package_file("reporting/headline_files")


def code_for(function):
    """Source files behind ``"cvsim6.module:function"``: its module and every package
    module that module imports, transitively, with the packages' ``__init__.py``
    (cvsim6.workflow.codegraph)."""
    return _codegraph.module_closure(function.split(":")[0], PACKAGE_DIR)


def attach_code_inputs():
    """Add the input ``code`` to each step that calls a package function (the ``function``
    param, the one place it is named): the source files of that function's import closure.
    A change of the code that produces an output then reruns that step and no other
    (Snakemake compares checksums of small inputs); call.py does not pass ``code`` on.
    Called once at the end of the Snakefile, after all steps are defined, the steps of the
    seed modules (seeds.smk) included; their copies of the Snakefile skip it. Each step keeps
    the path modifier of its own module (a step without inputs gets the workflow's)."""
    if not workflow.modifier.is_main_snakefile():
        return
    for each in workflow.rules:
        function = dict(each.params.items()).get("function")
        if function is not None:
            if each.input_modifier is None:
                # what Snakemake's own `input:` directive sets before adding files
                each.input_modifier = workflow.modifier.path_modifier
            each.set_input(code=code_for(function))


def study_priority(structural, ehr):
    """Job priority by the ``study`` wildcard. On few cores Snakemake starts the ready job of
    highest priority first: the structural chain (data -> emulator -> encoder/decoder ->
    study) is the workflow's longest, so it gets the higher value and starts first."""
    return lambda wildcards: structural if wildcards.study == "structural" else ehr


def ehr_csv(wildcards=None):
    """The EHR CSV: config ehr_data.path if set, else the copy downloaded into resources/."""
    return config["ehr_data"]["path"] or "resources/EHR_dataset.csv"


def noise_tag(delta):
    """File-name tag of a training-noise level, e.g. 0.5 -> '0.5', 1.0 -> '1'."""
    return f"{float(delta):g}"


def noise_tags(study):
    """File-name tags of ``study``'s training-noise levels in the config in use."""
    return [noise_tag(d) for d in config["training"]["studies"][study]["noise_levels"]]


def model_files(study, root=MODELS):
    """The networks of ``study`` under ``root``: emulator, then per noise level flow and encoder/decoder."""
    deltas = noise_tags(study)
    return dict(
        emulator=f"{root}/{study}/emulator.pt",
        flows=[f"{root}/{study}/flow_delta{d}.pt" for d in deltas],
        encoder_decoders=[
            f"{root}/{study}/encoder_decoder_delta{d}.pt" for d in deltas
        ],
    )


def network_targets(study):
    """Every network-dependent file of ``study`` for the config in use: the evaluation of
    the networks and, when the workflow trains them, the training tables and loss curves.
    """
    deltas = noise_tags(study)
    files = model_files(study)
    targets = [
        files["emulator"],
        *files["flows"],
        *files["encoder_decoders"],
        f"{NET_TABLES}/{study}_emulator_validation.md",
        f"{NET}/training/{study}/emulator_l2_errors.png",
    ]
    targets += [f"{NET}/training/{study}/flow_delta{d}_marginals.png" for d in deltas]
    if NETWORK_SOURCE == "trained":
        targets += [
            f"{TABLES}/{study}_architectures.md",
            f"{TABLES}/{study}_schedules.md",
            f"{RESULTS}/training/{study}/emulator_losses.png",
        ]
        targets += [
            f"{RESULTS}/training/{study}/{stage}_delta{d}_losses.png"
            for d in deltas
            for stage in ("flow", "encoder_decoder")
        ]
    return targets


def published_dir(wildcards=None):
    """The published files: config networks.published.path if set, else the copy fetched into resources/."""
    return config["networks"]["published"]["path"] or "resources/paper_networks"


def headline_files(root):
    """The workflow outputs under the network results ``root`` that the scorecard reads, the
    shared stiffness analysis included (cvsim6.reporting.headline_files)."""
    return _headlines.headline_files(RESULTS, root)


def scorecard_files(source):
    """The headline files of one network source ('trained' or 'published')."""
    return headline_files(NETWORK_RESULTS[source])


def optional_text(path):
    """The text of ``path`` if it exists, else None. Passed as a param, the text of an output
    of another target reruns the step when it appears or changes, without making that target
    part of this one's (e.g. the spread over seeds in the scorecard of `all`)."""
    return Path(path).read_text() if Path(path).is_file() else None


def calibration_figure_delta():
    """Noise level tag of the rank and recovery figures (ehr_study.figure_noise_level)."""
    return noise_tag(config["ehr_study"]["figure_noise_level"])


def encoder_decoder_candidates(wildcards):
    """The restart candidates' checkpoints of an encoder/decoder trained with ``restarts`` > 1
    (one job each, side by side), none without."""
    k = config["training"]["studies"][wildcards.study]["encoder_decoder"].get(
        "restarts", 1
    )
    model = (
        f"{RESULTS}/models/{wildcards.study}/encoder_decoder_delta{wildcards.delta}.pt"
    )
    return [f"{model}.ckpt.candidate{c}" for c in range(k)] if k > 1 else []


def invaert_training_losses(wildcards=None):
    """The encoder/decoder loss CSVs (their epoch seconds), when the networks are trained here."""
    if NETWORK_SOURCE != "trained":
        return []
    return [
        f"{RESULTS}/training/ehr/encoder_decoder_delta{d}_losses.csv"
        for d in noise_tags("ehr")
    ]


def seed_root(seed):
    """Results root of the networks of ``seed``: results/ for the default seed of a trained run."""
    if seed == config["seed"] and NETWORK_SOURCE == "trained":
        return RESULTS
    return f"{SEEDS_RESULTS}/{seed}"


def seed_config(seed):
    """The config of ``seed``'s module: this run's, with that seed and trained networks."""
    return {
        **config,
        "seed": seed,
        "networks": {**config["networks"], "source": "trained"},
    }


def seed_paths(seed):
    """Path prefixes moved under ``seed``'s root (everything network-dependent, and the logs)."""
    root = seed_root(seed)
    moved = ["models/", "training/", "tables/", "structural/", "ehr/predictions"]
    paths = {f"{RESULTS}/{p}": f"{root}/{p}" for p in moved}
    paths[f"{LOGS}/"] = f"{LOGS}/seeds/{seed}/"
    return paths


def published_headline_inputs(wildcards=None):
    """The published networks' headline files as named inputs ``published_<headline>`` when
    all of them exist, else none: their run is not part of target `seeds`, whose scorecard
    shows them beside the seeds and reruns when they appear or change."""
    files = scorecard_files("published")
    if not all(Path(p).is_file() for p in files.values()):
        return {}
    return {f"published_{key}": path for key, path in files.items()}


def seed_headline_files(wildcards=None):
    """The headline files of every seed, as named inputs ``seed<seed>_<headline>``."""
    return {
        f"seed{seed}_{key}": path
        for seed in config["seeds"]
        for key, path in headline_files(seed_root(seed)).items()
    }
