# Training data of the two studies (facts page: priors and splits): sample each
# prior from the master seed, simulate it in scattered shards, gather and split.

STUDIES = ["structural", "ehr"]
DATA = f"{RESULTS}/data"


wildcard_constraints:
    study="|".join(STUDIES),


rule sample_prior:
    output:
        parameters=f"{DATA}/{{study}}/parameters.parquet",
        shards=scatter.simulate(
            "results/data/{{study}}/shards/parameters_{scatteritem}.parquet"
        ),
    log:
        f"{LOGS}/sample_prior/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/sample_prior/{{study}}.tsv"
    priority: study_priority(2, 1)
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.data.datasets:sample_prior",
        prior=lambda w: config["data"]["studies"][w.study]["prior"],
        n_samples=lambda w: config["data"]["studies"][w.study]["n_samples"],
        seed=config["seed"],
        study=lambda w: w.study,
    script:
        "../scripts/call.py"


rule simulate_shard:
    input:
        parameters=f"{DATA}/{{study}}/shards/parameters_{{scatteritem}}.parquet",
    output:
        output=f"{DATA}/{{study}}/shards/simulated_{{scatteritem}}.parquet",
    log:
        f"{LOGS}/simulate_shard/{{study}}_{{scatteritem}}.log",
    benchmark:
        f"{BENCHMARKS}/simulate_shard/{{study}}_{{scatteritem}}.tsv"
    priority: study_priority(2, 1)
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1500,
        runtime=30,
    params:
        function="cvsim6.data.datasets:simulate_shard",
        shard=lambda w: w.scatteritem,
        simulator=config["simulator"],
    script:
        "../scripts/call.py"


rule gather_study:
    input:
        shards=gather.simulate(
            "results/data/{{study}}/shards/simulated_{scatteritem}.parquet"
        ),
    output:
        train=f"{DATA}/{{study}}/train.parquet",
        test=f"{DATA}/{{study}}/test.parquet",
        validation=f"{DATA}/{{study}}/validation.parquet",
        failures=f"{DATA}/{{study}}/failures.csv",
        manifest=f"{DATA}/{{study}}/manifest.json",
    log:
        f"{LOGS}/gather_study/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/gather_study/{{study}}.tsv"
    priority: study_priority(2, 1)
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.data.datasets:gather_study",
        study=lambda w: w.study,
        split=lambda w: config["data"]["studies"][w.study]["split"],
        prior=lambda w: config["data"]["studies"][w.study]["prior"],
        max_failure_fraction=config["data"]["max_failure_fraction"],
        seed=config["seed"],
        simulator=config["simulator"],
    script:
        "../scripts/call.py"


rule data_histogram_counts:
    input:
        train=rules.gather_study.output.train,
        test=rules.gather_study.output.test,
        validation=rules.gather_study.output.validation,
    output:
        counts=f"{DATA}/{{study}}/histograms.csv",
    log:
        f"{LOGS}/data_histogram_counts/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/data_histogram_counts/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.data.datasets:histogram_counts",
    script:
        "../scripts/call.py"


rule data_histograms:
    input:
        counts=rules.data_histogram_counts.output.counts,
    output:
        outputs_figure=report(
            f"{DATA}/{{study}}/outputs_histograms.png",
            category=report_study,
            subcategory="1 Data",
            caption="../report/data_outputs_histograms.rst",
        ),
        inputs_figure=report(
            f"{DATA}/{{study}}/inputs_histograms.png",
            category=report_study,
            subcategory="1 Data",
            caption="../report/data_inputs_histograms.rst",
        ),
    log:
        f"{LOGS}/data_histograms/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/data_histograms/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.data_figures:plot_histograms",
        study=lambda w: w.study,
    script:
        "../scripts/call.py"
