# Snakemake workflow reproducing Tong, Sing Long & Schiavazzi: inVAErt networks
# on the CVSim-6 lumped-parameter cardiovascular model.
#
# Run from the repository root, e.g.
#   snakemake --cores 2 --workflow-profile workflow/profiles/local all
# Rules live in workflow/rules/*.smk; every rule calls one function of the
# cvsim6 package through workflow/scripts/call.py. See README.md.

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/model_tables.smk"


localrules:
    all,


rule all:
    default_target: True
    input:
        rules.input_parameter_table.output,
        rules.output_parameter_table.output,
