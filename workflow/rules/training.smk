# Staged training of the inVAErt networks (paper section 2.2, appendix B): the
# emulator and the flows first (side by side), then the encoder/decoder through the
# frozen emulator; one flow and one encoder/decoder per training-noise level delta.

#: Where the training rules write the networks and their loss curves (whatever the source in use).
TRAINED_MODELS = f"{RESULTS}/models"
TRAINING = f"{RESULTS}/training"
#: Evaluation of the networks in use (trained or published).
NET_TRAINING = f"{NET}/training"


wildcard_constraints:
    delta=r"[0-9.]+",
    candidate=r"[0-9]+",
    network=r"emulator|(flow|encoder_decoder)_delta[0-9.]+",


rule network_tables:
    output:
        architecture_csv=f"{TABLES}/{{study}}_architectures.csv",
        architecture_md=report(
            f"{TABLES}/{{study}}_architectures.md",
            caption="../report/network_architectures.rst",
            category=report_study,
            subcategory="2 Networks",
        ),
        schedule_csv=f"{TABLES}/{{study}}_schedules.csv",
        schedule_md=report(
            f"{TABLES}/{{study}}_schedules.md",
            caption="../report/network_schedules.rst",
            category=report_study,
            subcategory="2 Networks",
        ),
    log:
        f"{LOGS}/network_tables/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/network_tables/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.network_tables:write_network_tables",
        training=config["training"],
        study=lambda w: w.study,
    script:
        "../scripts/call.py"


rule train_emulator:
    input:
        train=f"{DATA}/{{study}}/train.parquet",
        test=f"{DATA}/{{study}}/test.parquet",
    output:
        model=f"{TRAINED_MODELS}/{{study}}/emulator.pt",
        losses=f"{TRAINING}/{{study}}/emulator_losses.csv",
    log:
        f"{LOGS}/train_emulator/{{study}}.log",
    benchmark:
        f"{BENCHMARKS}/train_emulator/{{study}}.tsv"
    priority: study_priority(3, 2)
    conda:
        "../envs/cvsim6.yaml"
    threads: config["training"]["threads"]
    resources:
        mem_mb=4000,
        runtime=240,
    params:
        function="cvsim6.training.train:train_emulator",
        hyper=lambda w: config["training"]["studies"][w.study]["emulator"],
        seed=config["seed"],
        device=config["training"]["device"],
        checkpoint_every=config["training"]["checkpoint_every"],
    script:
        "../scripts/call.py"


rule train_flow:
    input:
        train=f"{DATA}/{{study}}/train.parquet",
        test=f"{DATA}/{{study}}/test.parquet",
    output:
        model=f"{TRAINED_MODELS}/{{study}}/flow_delta{{delta}}.pt",
        losses=f"{TRAINING}/{{study}}/flow_delta{{delta}}_losses.csv",
    log:
        f"{LOGS}/train_flow/{{study}}_delta{{delta}}.log",
    benchmark:
        f"{BENCHMARKS}/train_flow/{{study}}_delta{{delta}}.tsv"
    priority: study_priority(1, 0)
    conda:
        "../envs/cvsim6.yaml"
    threads: config["training"]["threads"]
    resources:
        mem_mb=4000,
        runtime=240,
    params:
        function="cvsim6.training.train:train_flow",
        hyper=lambda w: config["training"]["studies"][w.study]["flow"],
        noise_level=lambda w: float(w.delta),
        seed=config["seed"],
        device=config["training"]["device"],
        checkpoint_every=config["training"]["checkpoint_every"],
    script:
        "../scripts/call.py"


rule train_encoder_decoder_candidate:
    input:
        train=f"{DATA}/{{study}}/train.parquet",
        test=f"{DATA}/{{study}}/test.parquet",
        emulator=rules.train_emulator.output.model,
    output:
        checkpoint=f"{TRAINED_MODELS}/{{study}}/encoder_decoder_delta{{delta}}.pt.ckpt.candidate{{candidate}}",
        losses=f"{TRAINED_MODELS}/{{study}}/encoder_decoder_delta{{delta}}.pt.ckpt.candidate{{candidate}}.csv",
    log:
        f"{LOGS}/train_encoder_decoder_candidate/{{study}}_delta{{delta}}_{{candidate}}.log",
    benchmark:
        f"{BENCHMARKS}/train_encoder_decoder_candidate/{{study}}_delta{{delta}}_{{candidate}}.tsv"
    priority: study_priority(3, 1)
    conda:
        "../envs/cvsim6.yaml"
    threads: config["training"]["threads"]
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        function="cvsim6.training.train:train_encoder_decoder",
        candidate=lambda w: int(w.candidate),
        model=lambda w: f"{TRAINED_ROOT}/models/{w.study}/encoder_decoder_delta{w.delta}.pt",
        hyper=lambda w: config["training"]["studies"][w.study]["encoder_decoder"],
        noise_level=lambda w: float(w.delta),
        seed=config["seed"],
        device=config["training"]["device"],
        checkpoint_every=config["training"]["checkpoint_every"],
    script:
        "../scripts/call.py"


rule train_encoder_decoder:
    input:
        train=f"{DATA}/{{study}}/train.parquet",
        test=f"{DATA}/{{study}}/test.parquet",
        emulator=rules.train_emulator.output.model,
        candidates=encoder_decoder_candidates,
    output:
        model=f"{TRAINED_MODELS}/{{study}}/encoder_decoder_delta{{delta}}.pt",
        losses=f"{TRAINING}/{{study}}/encoder_decoder_delta{{delta}}_losses.csv",
    log:
        f"{LOGS}/train_encoder_decoder/{{study}}_delta{{delta}}.log",
    benchmark:
        f"{BENCHMARKS}/train_encoder_decoder/{{study}}_delta{{delta}}.tsv"
    priority: study_priority(3, 1)
    conda:
        "../envs/cvsim6.yaml"
    threads: config["training"]["threads"]
    resources:
        mem_mb=4000,
        runtime=480,
    params:
        function="cvsim6.training.train:train_encoder_decoder",
        hyper=lambda w: config["training"]["studies"][w.study]["encoder_decoder"],
        noise_level=lambda w: float(w.delta),
        seed=config["seed"],
        device=config["training"]["device"],
        checkpoint_every=config["training"]["checkpoint_every"],
    script:
        "../scripts/call.py"


rule plot_training_losses:
    input:
        losses=f"{TRAINING}/{{study}}/{{network}}_losses.csv",
        model=f"{TRAINED_MODELS}/{{study}}/{{network}}.pt",
    output:
        figure=report(
            f"{TRAINING}/{{study}}/{{network}}_losses.png",
            caption="../report/training_losses.rst",
            category=report_study,
            subcategory="2 Networks",
        ),
    log:
        f"{LOGS}/plot_training_losses/{{study}}_{{network}}.log",
    benchmark:
        f"{BENCHMARKS}/plot_training_losses/{{study}}_{{network}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.loss_figures:plot_training_losses",
        network=lambda w: w.network,
        study=lambda w: w.study,
    script:
        "../scripts/call.py"


rule emulator_validation:
    input:
        model=f"{MODELS}/{{study}}/emulator.pt",
        validation=f"{DATA}/{{study}}/validation.parquet",
    output:
        csv=f"{NET_TABLES}/{{study}}_emulator_validation.csv",
        md=report(
            f"{NET_TABLES}/{{study}}_emulator_validation.md",
            caption="../report/emulator_validation.rst",
            category=report_study,
            subcategory=f"2 Networks{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/emulator_validation/{{study}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/emulator_validation/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.evaluation:emulator_validation",
        study=lambda w: w.study,
    script:
        "../scripts/call.py"


rule emulator_l2_errors:
    input:
        model=f"{MODELS}/{{study}}/emulator.pt",
        validation=f"{DATA}/{{study}}/validation.parquet",
    output:
        errors=f"{NET_TRAINING}/{{study}}/emulator_l2_errors.csv",
        summary=f"{NET_TRAINING}/{{study}}/emulator_l2_errors.json",
    log:
        f"{NET_LOGS}/emulator_l2_errors/{{study}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/emulator_l2_errors/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    params:
        function="cvsim6.studies.evaluation:emulator_l2_errors",
        study=lambda w: w.study,
    script:
        "../scripts/call.py"


rule emulator_l2_histogram:
    input:
        errors=rules.emulator_l2_errors.output.errors,
        summary=rules.emulator_l2_errors.output.summary,
    output:
        figure=report(
            f"{NET_TRAINING}/{{study}}/emulator_l2_errors.png",
            caption="../report/emulator_l2.rst",
            category=report_study,
            subcategory=f"2 Networks{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/emulator_l2_histogram/{{study}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/emulator_l2_histogram/{{study}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.evaluation_figures:emulator_l2_histogram",
    script:
        "../scripts/call.py"


rule flow_samples:
    input:
        flow=f"{MODELS}/{{study}}/flow_delta{{delta}}.pt",
    output:
        samples=f"{NET_TRAINING}/{{study}}/flow_delta{{delta}}_samples.parquet",
    log:
        f"{NET_LOGS}/flow_samples/{{study}}_delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/flow_samples/{{study}}_delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    params:
        function="cvsim6.studies.evaluation:flow_samples",
        n_samples=20000,
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule flow_marginals:
    input:
        samples=rules.flow_samples.output.samples,
        validation=f"{DATA}/{{study}}/validation.parquet",
    output:
        figure=report(
            f"{NET_TRAINING}/{{study}}/flow_delta{{delta}}_marginals.png",
            caption="../report/flow_marginals.rst",
            category=report_study,
            subcategory=f"2 Networks{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/flow_marginals/{{study}}_delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/flow_marginals/{{study}}_delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    params:
        function="cvsim6.reporting.evaluation_figures:flow_marginals",
    script:
        "../scripts/call.py"
