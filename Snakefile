# Snakemake workflow reproducing Tong, Sing Long & Schiavazzi: inVAErt networks
# on the CVSim-6 lumped-parameter cardiovascular model.
#
# Run from the repository root, e.g.
#   snakemake --cores 2 --workflow-profile workflow/profiles/local all
# Rules live in workflow/rules/*.smk; every rule calls one function of the
# cvsim6 package through workflow/scripts/call.py, named once in `params: function`;
# attach_code_inputs() (common.smk, last line here) adds that function's source files
# as the rule's `code` input, so editing a module reruns only the rules that import it.

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


scattergather:
    simulate=config["data"]["n_shards"],


include: "workflow/rules/common.smk"
include: "workflow/rules/model_tables.smk"
include: "workflow/rules/stiffness.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/ehr.smk"
include: "workflow/rules/training.smk"
include: "workflow/rules/structural.smk"
include: "workflow/rules/published.smk"
include: "workflow/rules/scorecard.smk"
include: "workflow/rules/calibration.smk"
include: "workflow/rules/references.smk"
include: "workflow/rules/seeds.smk"


localrules:
    all,
    calibration,
    seeds,
    download_ehr,
    fetch_published_networks,


rule all:
    default_target: True
    input:
        rules.input_parameter_table.output,
        rules.output_parameter_table.output,
        rules.stiffness_extremes.output,
        rules.stiffness_eigenvalue_figure.output,
        expand(rules.stiffness_radar_figure.output, extreme=["max", "min"]),
        rules.stiffness_sr_figure.output,
        rules.stiffness_rk4.output,
        rules.stiffness_rk4_figure.output,
        expand(rules.gather_study.output, study=STUDIES),
        expand(rules.data_histograms.output, study=STUDIES),
        rules.ehr_patients.output,
        [network_targets(study) for study in STUDIES],
        rules.ehr_error_table.output,
        rules.structural_inversion_table.output,
        rules.structural_reconstruction.output,
        rules.structural_parallel_coordinates.output,
        rules.structural_manifold_svd.output,
        rules.structural_missing_data.output,
        rules.structural_jacobian.output,
        rules.structural_reconstruction_figure.output,
        rules.structural_parallel_coordinates_figure.output,
        rules.structural_manifold_svd_figure.output,
        rules.structural_missing_data_figure.output,
        rules.structural_jacobian_figure.output,
        expand(
            rules.ehr_ood_table.output,
            delta=noise_tag(config["ehr_study"]["figure_noise_level"]),
        ),
        expand(
            rules.ehr_patient_figure.output,
            delta=noise_tag(config["ehr_study"]["figure_noise_level"]),
        ),
        rules.reproduction_scorecard.output,


attach_code_inputs()
