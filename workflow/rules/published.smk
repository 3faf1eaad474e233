# The paper's published networks (networks.source: published): fetched from their
# public origin at a pinned commit (or a configured local copy), every file checked
# against its SHA-256, and converted into this project's model files under
# results/published/models/, so that every downstream rule uses them unchanged.

PUBLISHED_MODELS = f"{NETWORK_RESULTS['published']}/models"


rule fetch_published_networks:
    output:
        directory=directory("resources/paper_networks"),
    log:
        f"{LOGS}/fetch_published_networks.log",
    benchmark:
        f"{BENCHMARKS}/fetch_published_networks.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=10,
    params:
        function="cvsim6.nets.published:fetch_published_networks",
        base_url=config["networks"]["published"]["url"],
    script:
        "../scripts/call.py"


for _study in STUDIES:

    rule:
        name:
            f"convert_published_{_study}"
        input:
            directory=published_dir,
        output:
            **model_files(_study, PUBLISHED_MODELS),
        log:
            f"{LOGS}/published/convert_published/{_study}.log",
        benchmark:
            f"{BENCHMARKS}/published/convert_published/{_study}.tsv"
        conda:
            "../envs/cvsim6.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            function="cvsim6.nets.published:convert_published_study",
            study=_study,
            noise_levels=config["training"]["studies"][_study]["noise_levels"],
        script:
            "../scripts/call.py"
