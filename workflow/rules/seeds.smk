# Spread over seeds (target `seeds`, not part of `all`): the network stages behind every
# headline (training, then the evaluations the scorecard reads), once per seed of config
# `seeds`. Each extra seed is a Snakemake module of this same workflow with config `seed`
# set to it and its network results under results/seeds/<seed>/ (logs under
# logs/seeds/<seed>/); the simulated data and the EHR patients of `all` are shared, so the
# seeds vary the networks' initialisation, training noise and inference sampling only.
# The default seed's networks are those of `all`.

# The modules load this Snakefile again; only the main workflow defines them (no nesting).
if workflow.modifier.is_main_snakefile():
    for seed in config["seeds"]:
        if seed_root(seed) == RESULTS:
            continue
        seed_module = f"seed_{seed}"
        seed_rule_prefix = f"seed_{seed}_"

        module:
            name: seed_module
            snakefile:
                workflow.main_snakefile
            config:
                seed_config(seed)
            replace_prefix:
                seed_paths(seed)
        # the rules behind the scorecard's headlines (cvsim6.reporting.headline_files),
        # from one load of the module (snakefmt 2.1 cannot parse a list of rules here)
        # fmt: off
        use rule train_emulator, train_flow, train_encoder_decoder_candidate, train_encoder_decoder, emulator_validation, emulator_l2_errors, structural_inversion_table, structural_observation, structural_manifold, structural_reconstruction, structural_manifold_svd, structural_missing_data, invert_ehr_patients, ehr_error_table from seed_module as seed_rule_prefix*
        # fmt: on
rule seed_scorecard:
    input:
        unpack(seed_headline_files),
        unpack(published_headline_inputs),
    output:
        csv=SEED_SCORECARD,
        md=report(
            f"{RESULTS}/report/seeds.md",
            caption="../report/seed_scorecard.rst",
            category=REPORT_SCORECARD,
        ),
        best_delta_csv=f"{RESULTS}/report/seeds_best_delta.csv",
        best_delta_md=report(
            f"{RESULTS}/report/seeds_best_delta.md",
            caption="../report/seed_best_delta.rst",
            category=REPORT_SCORECARD,
        ),
    log:
        f"{LOGS}/seed_scorecard.log",
    benchmark:
        f"{BENCHMARKS}/seed_scorecard.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.reporting.seed_scorecard:write_seed_scorecard",
        seeds=config["seeds"],
        default_seed=config["seed"],
    script:
        "../scripts/call.py"


rule seeds:
    input:
        rules.seed_scorecard.output,
