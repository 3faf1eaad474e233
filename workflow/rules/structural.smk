# Structural identifiability study (paper section 3.3 and appendix C), from the
# networks trained on the structural data (noise-free, delta = 0). Each computing rule
# writes data only (tables, JSON, CSV); its `<name>_figure` rule draws the figure from
# those files (cvsim6.reporting.structural_figures), so a figure edit reruns that rule only.

STRUCT = f"{NET}/structural"
SCFG = config["structural_study"]
S_MODELS = f"{MODELS}/structural"


rule structural_inversion_table:
    input:
        encoder_decoder=f"{S_MODELS}/encoder_decoder_delta0.pt",
        validation=f"{DATA}/structural/validation.parquet",
    output:
        csv=f"{NET_TABLES}/structural_inversion_errors.csv",
        summary=f"{NET_TABLES}/structural_inversion_errors.json",
        md=report(
            f"{NET_TABLES}/structural_inversion_errors.md",
            caption="../report/structural_inversion_table.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_inversion_table.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_inversion_table.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.structural:inversion_table",
        simulator=config["simulator"],
        corrector_steps=config["structural_study"]["corrector_steps"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule structural_observation:
    input:
        flow=f"{S_MODELS}/flow_delta0.pt",
    output:
        csv=f"{NET_TABLES}/structural_observation.csv",
        md=report(
            f"{NET_TABLES}/structural_observation.md",
            caption="../report/structural_observation.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_observation.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_observation.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.structural:choose_observation",
        source=SCFG["observation"],
        n_flow_samples=SCFG["observation_flow_samples"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule structural_manifold:
    input:
        encoder_decoder=f"{S_MODELS}/encoder_decoder_delta0.pt",
        observation=rules.structural_observation.output.csv,
    output:
        samples=f"{STRUCT}/manifold_samples.parquet",
    log:
        f"{NET_LOGS}/structural_manifold.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_manifold.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.structural:sample_manifold",
        n_samples=SCFG["n_manifold"],
        corrector_steps=config["structural_study"]["corrector_steps"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule structural_reconstruction:
    input:
        samples=rules.structural_manifold.output.samples,
        observation=rules.structural_observation.output.csv,
        emulator=f"{S_MODELS}/emulator.pt",
    output:
        csv=f"{NET_TABLES}/structural_manifold_reconstruction.csv",
        summary=f"{NET_TABLES}/structural_manifold_reconstruction.json",
        md=report(
            f"{NET_TABLES}/structural_manifold_reconstruction.md",
            caption="../report/structural_reconstruction_table.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
        traces=f"{STRUCT}/manifold_trajectories.csv",
    log:
        f"{NET_LOGS}/structural_reconstruction.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_reconstruction.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.structural:manifold_reconstruction",
        simulator=config["simulator"],
        n_reconstruct=SCFG["n_reconstruct"],
        n_traces=SCFG["n_traces"],
        n_spread=SCFG["n_spread"],
        spread_resamples=SCFG["spread_resamples"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule structural_reconstruction_figure:
    input:
        traces=rules.structural_reconstruction.output.traces,
        observation=rules.structural_observation.output.csv,
        summary=rules.structural_reconstruction.output.summary,
    output:
        figure=report(
            f"{STRUCT}/manifold_trajectories.png",
            caption="../report/structural_trajectories.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_reconstruction_figure.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_reconstruction_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.structural_figures:manifold_trajectories_figure",
        n_traces=SCFG["n_traces"],
    script:
        "../scripts/call.py"


rule structural_parallel_coordinates:
    input:
        samples=rules.structural_manifold.output.samples,
    output:
        lines=f"{STRUCT}/manifold_parallel_coordinates.csv",
        summary=f"{STRUCT}/manifold_parallel_coordinates.json",
    log:
        f"{NET_LOGS}/structural_parallel_coordinates.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_parallel_coordinates.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.structural:parallel_coordinates_data",
        prior=config["data"]["studies"]["structural"]["prior"],
        n_lines=SCFG["n_reconstruct"],
    script:
        "../scripts/call.py"


rule structural_parallel_coordinates_figure:
    input:
        lines=rules.structural_parallel_coordinates.output.lines,
        summary=rules.structural_parallel_coordinates.output.summary,
    output:
        figure=report(
            f"{STRUCT}/manifold_parallel_coordinates.png",
            caption="../report/structural_parallel_coordinates.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_parallel_coordinates_figure.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_parallel_coordinates_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.structural_figures:parallel_coordinates_figure",
    script:
        "../scripts/call.py"


rule structural_manifold_svd:
    input:
        samples=rules.structural_manifold.output.samples,
    output:
        csv=f"{STRUCT}/manifold_svd.csv",
        summary=f"{STRUCT}/manifold_svd.json",
    log:
        f"{NET_LOGS}/structural_manifold_svd.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_manifold_svd.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.structural:manifold_svd_modes",
    script:
        "../scripts/call.py"


rule structural_manifold_svd_figure:
    input:
        csv=rules.structural_manifold_svd.output.csv,
        summary=rules.structural_manifold_svd.output.summary,
    output:
        figure=report(
            f"{STRUCT}/manifold_svd.png",
            caption="../report/structural_svd.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_manifold_svd_figure.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_manifold_svd_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.structural_figures:manifold_svd_figure",
    script:
        "../scripts/call.py"


rule structural_missing_data:
    input:
        flow=f"{S_MODELS}/flow_delta0.pt",
        encoder_decoder=f"{S_MODELS}/encoder_decoder_delta0.pt",
        observation=rules.structural_observation.output.csv,
    output:
        csv=f"{NET_TABLES}/structural_missing_data.csv",
        summary=f"{NET_TABLES}/structural_missing_data.json",
        md=report(
            f"{NET_TABLES}/structural_missing_data.md",
            caption="../report/structural_missing_table.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
        traces=f"{STRUCT}/missing_data_trajectories.csv",
    log:
        f"{NET_LOGS}/structural_missing_data.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_missing_data.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        function="cvsim6.studies.structural:missing_data",
        simulator=config["simulator"],
        missing=SCFG["missing"],
        n_flow_samples=SCFG["missing_flow_samples"],
        top_k=SCFG["missing_top"],
        n_latent=SCFG["missing_latent"],
        corrector_steps=config["structural_study"]["corrector_steps"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule structural_missing_data_figure:
    input:
        traces=rules.structural_missing_data.output.traces,
        observation=rules.structural_observation.output.csv,
    output:
        figure=report(
            f"{STRUCT}/missing_data_trajectories.png",
            caption="../report/structural_missing.rst",
            category=REPORT_STUDY["structural"],
            subcategory=f"3 Inversion and non-identifiable manifold{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_missing_data_figure.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_missing_data_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.structural_figures:missing_data_figure",
        missing=SCFG["missing"],
        top_k=SCFG["missing_top"],
        n_latent=SCFG["missing_latent"],
    script:
        "../scripts/call.py"


rule structural_jacobian:
    input:
        samples=rules.structural_manifold.output.samples,
    output:
        csv=f"{NET_TABLES}/structural_local_identifiability.csv",
        summary=f"{NET_TABLES}/structural_local_identifiability.json",
        md=report(
            f"{NET_TABLES}/structural_local_identifiability.md",
            caption="../report/structural_local_identifiability.rst",
            category=REPORT_BEYOND,
            subcategory=f"1 Local identifiability (Jacobian){NET_MARK}",
        ),
        spectra=f"{STRUCT}/jacobian_spectra.csv",
    log:
        f"{NET_LOGS}/structural_jacobian.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_jacobian.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=15,
    params:
        function="cvsim6.studies.structural:jacobian_check",
        prior=config["data"]["studies"]["structural"]["prior"],
        simulator=config["simulator"],
        n_points=SCFG["jacobian_points"],
        rel_step=SCFG["jacobian_rel_step"],
        rank_rtol=SCFG["rank_rtol"],
    script:
        "../scripts/call.py"


rule structural_jacobian_figure:
    input:
        spectra=rules.structural_jacobian.output.spectra,
    output:
        figure=report(
            f"{STRUCT}/jacobian_spectra.png",
            caption="../report/structural_jacobian.rst",
            category=REPORT_BEYOND,
            subcategory=f"1 Local identifiability (Jacobian){NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/structural_jacobian_figure.log",
    benchmark:
        f"{NET_BENCHMARKS}/structural_jacobian_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.structural_figures:jacobian_spectra_figure",
        rank_rtol=SCFG["rank_rtol"],
    script:
        "../scripts/call.py"
