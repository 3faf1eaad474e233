# Section 3.1 of the paper: stiffness of CVSim-6 at the default parameters.
# Eigen-analysis of the Jacobian A(t) along the Radau reference trajectory,
# stiffness ratio SR(t), eigenvectors at the SR extremes, and explicit RK4.

STIFFNESS = f"{RESULTS}/stiffness"


rule stiffness_eigen:
    output:
        eigenvalues=f"{STIFFNESS}/eigenvalues.csv",
        trajectory=f"{STIFFNESS}/trajectory.csv",
    log:
        f"{LOGS}/stiffness_eigen.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_eigen.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        function="cvsim6.model.stiffness:eigen_analysis",
        rtol=config["stiffness"]["rtol"],
        samples_per_cycle=config["stiffness"]["samples_per_cycle"],
        zero_eigenvalue_tol=config["stiffness"]["zero_eigenvalue_tol"],
        sr_tol=config["stiffness"]["sr_tol"],
    script:
        "../scripts/call.py"


rule stiffness_extremes:
    input:
        eigenvalues=rules.stiffness_eigen.output.eigenvalues,
        trajectory=rules.stiffness_eigen.output.trajectory,
    output:
        eigenvectors=f"{STIFFNESS}/eigenvectors_sr_extremes.csv",
        csv=f"{STIFFNESS}/sr_extremes.csv",
        md=report(
            f"{STIFFNESS}/sr_extremes.md",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_extremes.rst",
        ),
    log:
        f"{LOGS}/stiffness_extremes.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_extremes.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.model.stiffness:extremes",
        zero_eigenvalue_tol=config["stiffness"]["zero_eigenvalue_tol"],
        sr_tol=config["stiffness"]["sr_tol"],
    script:
        "../scripts/call.py"


rule stiffness_eigenvalue_figure:
    input:
        eigenvalues=rules.stiffness_eigen.output.eigenvalues,
    output:
        png=report(
            f"{STIFFNESS}/eigenvalues.png",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_eigenvalues.rst",
        ),
        pdf=f"{STIFFNESS}/eigenvalues.pdf",
    log:
        f"{LOGS}/stiffness_eigenvalue_figure.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_eigenvalue_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.stiffness_figures:eigenvalue_figure",
        zero_eigenvalue_tol=config["stiffness"]["zero_eigenvalue_tol"],
    script:
        "../scripts/call.py"


rule stiffness_radar_figure:
    input:
        eigenvectors=rules.stiffness_extremes.output.eigenvectors,
    output:
        png=report(
            f"{STIFFNESS}/radar_sr_{{extreme}}.png",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_radar.rst",
        ),
        pdf=f"{STIFFNESS}/radar_sr_{{extreme}}.pdf",
    log:
        f"{LOGS}/stiffness_radar_figure/{{extreme}}.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_radar_figure/{{extreme}}.tsv"
    wildcard_constraints:
        extreme="max|min",
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.stiffness_figures:radar_figure",
        instant=lambda wildcards: f"SR {wildcards.extreme}",
    script:
        "../scripts/call.py"


rule stiffness_sr_figure:
    input:
        eigenvalues=rules.stiffness_eigen.output.eigenvalues,
        trajectory=rules.stiffness_eigen.output.trajectory,
    output:
        png=report(
            f"{STIFFNESS}/sr_dynamics.png",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_sr_dynamics.rst",
        ),
        pdf=f"{STIFFNESS}/sr_dynamics.pdf",
    log:
        f"{LOGS}/stiffness_sr_figure.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_sr_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.stiffness_figures:sr_dynamics_figure",
    script:
        "../scripts/call.py"


rule stiffness_rk4:
    output:
        series=f"{STIFFNESS}/rk4_series.csv",
        csv=f"{STIFFNESS}/rk4_errors.csv",
        md=report(
            f"{STIFFNESS}/rk4_errors.md",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_rk4_table.rst",
        ),
    log:
        f"{LOGS}/stiffness_rk4.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_rk4.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        function="cvsim6.model.stiffness:rk4_study",
        rtol=config["stiffness"]["rtol"],
        rk4_steps=config["stiffness"]["rk4_steps"],
        samples_per_cycle=config["stiffness"]["samples_per_cycle"],
    script:
        "../scripts/call.py"


rule stiffness_rk4_figure:
    input:
        series=rules.stiffness_rk4.output.series,
    output:
        png=report(
            f"{STIFFNESS}/rk4.png",
            category=REPORT_STIFFNESS,
            caption="../report/stiffness_rk4.rst",
        ),
        pdf=f"{STIFFNESS}/rk4.pdf",
    log:
        f"{LOGS}/stiffness_rk4_figure.log",
    benchmark:
        f"{BENCHMARKS}/stiffness_rk4_figure.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.stiffness_figures:rk4_figure",
    script:
        "../scripts/call.py"
