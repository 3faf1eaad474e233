# Calibration of the inverse on simulated EHR-prior cases, inVAErt beside sbi's neural
# posterior estimation (NPE), and the EHR patients inverted three ways (beyond the paper).
# Target: snakemake --cores 2 --workflow-profile workflow/profiles/local calibration

#: Calibration samples and figures of the networks in use (trained or published).
CALIBRATION = f"{NET}/calibration"


rule train_npe:
    input:
        train=f"{DATA}/ehr/train.parquet",
    output:
        model=f"{TRAINED_MODELS}/ehr/npe_delta{{delta}}.pt",
        losses=f"{TRAINING}/ehr/npe_delta{{delta}}_losses.csv",
    log:
        f"{LOGS}/train_npe/delta{{delta}}.log",
    benchmark:
        f"{BENCHMARKS}/train_npe/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        function="cvsim6.inference.npe:train_npe",
        prior=config["data"]["studies"]["ehr"]["prior"],
        hyper=config["calibration"]["npe"],
        noise_level=lambda w: float(w.delta),
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule plot_npe_losses:
    input:
        losses=rules.train_npe.output.losses,
    output:
        figure=report(
            f"{TRAINING}/ehr/npe_delta{{delta}}_losses.png",
            caption="../report/npe_losses.rst",
            category=REPORT_BEYOND,
            subcategory="4 NPE baseline training",
        ),
    log:
        f"{LOGS}/plot_npe_losses/delta{{delta}}.log",
    benchmark:
        f"{BENCHMARKS}/plot_npe_losses/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.loss_figures:plot_training_losses",
        network=lambda w: f"npe_delta{w.delta}",
    script:
        "../scripts/call.py"


rule calibration_samples:
    input:
        validation=f"{DATA}/ehr/validation.parquet",
        encoder_decoder=f"{MODELS}/ehr/encoder_decoder_delta{{delta}}.pt",
        npe=rules.train_npe.output.model,
    output:
        samples=f"{CALIBRATION}/samples_delta{{delta}}.npz",
    log:
        f"{NET_LOGS}/calibration_samples/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/calibration_samples/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        function="cvsim6.studies.calibration:calibration_samples",
        noise_level=lambda w: float(w.delta),
        n_cases=config["calibration"]["n_cases"],
        n_samples=config["calibration"]["n_samples"],
        corrector_steps=config["ehr_study"]["corrector_steps"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule calibration_summary:
    input:
        samples=expand(
            f"{CALIBRATION}/samples_delta{{delta}}.npz", delta=noise_tags("ehr")
        ),
        npe_models=expand(
            f"{TRAINED_MODELS}/ehr/npe_delta{{delta}}.pt", delta=noise_tags("ehr")
        ),
        invaert_losses=invaert_training_losses,
    output:
        csv=f"{NET_TABLES}/calibration_summary.csv",
        md=report(
            f"{NET_TABLES}/calibration_summary.md",
            caption="../report/calibration_summary.rst",
            category=REPORT_BEYOND,
            subcategory=f"3 Calibration: inVAErt and NPE{NET_MARK}",
        ),
        figure_data=f"{CALIBRATION}/figure_data.npz",
    log:
        f"{NET_LOGS}/calibration_summary.log",
    benchmark:
        f"{NET_BENCHMARKS}/calibration_summary.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        function="cvsim6.studies.calibration:calibration_summary",
        prior=config["data"]["studies"]["ehr"]["prior"],
        simulator=config["simulator"],
        figure_noise_level=config["ehr_study"]["figure_noise_level"],
        identifiability_points=config["calibration"]["identifiability_points"],
        rel_step=config["structural_study"]["jacobian_rel_step"],
        rank_rtol=config["structural_study"]["rank_rtol"],
        nonidentifiable_share=config["calibration"]["nonidentifiable_share"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule calibration_figures:
    input:
        figure_data=rules.calibration_summary.output.figure_data,
    output:
        coverage_figure=report(
            f"{CALIBRATION}/coverage.png",
            caption="../report/calibration_coverage.rst",
            category=REPORT_BEYOND,
            subcategory=f"3 Calibration: inVAErt and NPE{NET_MARK}",
        ),
        rank_figure=report(
            f"{CALIBRATION}/rank_ecdf_delta{calibration_figure_delta()}.png",
            caption="../report/calibration_ranks.rst",
            category=REPORT_BEYOND,
            subcategory=f"3 Calibration: inVAErt and NPE{NET_MARK}",
        ),
        recovery_figure=report(
            f"{CALIBRATION}/recovery_delta{calibration_figure_delta()}.png",
            caption="../report/calibration_recovery.rst",
            category=REPORT_BEYOND,
            subcategory=f"3 Calibration: inVAErt and NPE{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/calibration_figures.log",
    benchmark:
        f"{NET_BENCHMARKS}/calibration_figures.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.reporting.calibration_figures:calibration_figures",
    script:
        "../scripts/call.py"


rule simulate_ehr_predictions:
    input:
        predictions=f"{NET_EHR}/predictions_delta{{delta}}.parquet",
    output:
        simulated=f"{NET_EHR}/predictions_delta{{delta}}_simulated.parquet",
    log:
        f"{NET_LOGS}/simulate_ehr_predictions/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/simulate_ehr_predictions/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        function="cvsim6.studies.ehr_methods:simulate_ehr_predictions",
        simulator=config["simulator"],
    script:
        "../scripts/call.py"


rule invert_ehr_npe:
    input:
        predictions=f"{NET_EHR}/predictions_delta{{delta}}.parquet",
        npe=rules.train_npe.output.model,
    output:
        npe_predictions=f"{NET_EHR}/npe_predictions_delta{{delta}}.parquet",
    log:
        f"{NET_LOGS}/invert_ehr_npe/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/invert_ehr_npe/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        function="cvsim6.studies.ehr_methods:invert_ehr_npe",
        simulator=config["simulator"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule ehr_error_methods:
    input:
        patients=rules.ehr_patients.output.patients,
        emulated=expand(
            f"{NET_EHR}/predictions_delta{{delta}}.parquet", delta=noise_tags("ehr")
        ),
        invaert_simulated=expand(
            rules.simulate_ehr_predictions.output.simulated, delta=noise_tags("ehr")
        ),
        npe_simulated=expand(
            rules.invert_ehr_npe.output.npe_predictions, delta=noise_tags("ehr")
        ),
    output:
        csv=f"{NET_TABLES}/ehr_error_methods.csv",
        md=report(
            f"{NET_TABLES}/ehr_error_methods.md",
            caption="../report/ehr_error_methods.rst",
            category=REPORT_BEYOND,
            subcategory=f"3 Calibration: inVAErt and NPE{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/ehr_error_methods.log",
    benchmark:
        f"{NET_BENCHMARKS}/ehr_error_methods.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.ehr_methods:ehr_error_methods",
        figure_noise_level=config["ehr_study"]["figure_noise_level"],
    script:
        "../scripts/call.py"


rule calibration:
    input:
        rules.calibration_summary.output,
        rules.calibration_figures.output,
        rules.ehr_error_methods.output,
        expand(rules.plot_npe_losses.output.figure, delta=noise_tags("ehr")),
