# Classical references beside the data-driven study (beyond the paper): Sobol global
# sensitivity of the 16 outputs under both priors, and MCMC reference posteriors (exact
# simulator) for simulated calibration cases and EHR patients, compared with inVAErt and NPE.
# Target: snakemake --cores 2 --workflow-profile workflow/profiles/local references

#: Results that do not depend on the networks (Sobol indices, MCMC chains).
REFERENCES = f"{RESULTS}/references"
#: Comparisons with the networks in use (trained or published).
NET_REFERENCES = f"{NET}/references"
REF = config["references"]
#: Noise level of the reference posteriors, as a file-name tag.
REF_DELTA = noise_tag(REF["noise_level"])
#: Case names: simulated calibration cases sim0.., then EHR patients ehr.. (cvsim6.studies.references.case_names).
REF_CASES = [f"sim{i}" for i in range(REF["mcmc"]["n_simulated"])] + [
    f"ehr{i}" for i in range(REF["mcmc"]["n_patients"])
]
REF_PRIORS = ["structural", "ehr"]


wildcard_constraints:
    prior="|".join(REF_PRIORS),
    case=r"(sim|ehr)[0-9]+",


localrules:
    references,


rule sobol_prior:
    output:
        indices_csv=f"{REFERENCES}/sobol_{{prior}}.csv",
    log:
        f"{LOGS}/sobol_prior/{{prior}}.log",
    benchmark:
        f"{BENCHMARKS}/sobol_prior/{{prior}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
    params:
        function="cvsim6.studies.sensitivity:sobol_prior",
        prior_name=lambda w: w.prior,
        prior=lambda w: config["data"]["studies"][w.prior]["prior"],
        simulator=config["simulator"],
        n_base=REF["sobol"]["n_base"],
        bootstrap=REF["sobol"]["bootstrap"],
        conf_level=REF["sobol"]["conf_level"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule sobol_tables:
    input:
        indices=expand(rules.sobol_prior.output.indices_csv, prior=REF_PRIORS),
    output:
        csv=f"{TABLES}/sensitivity_sobol.csv",
        md=report(
            f"{TABLES}/sensitivity_sobol.md",
            caption="../report/sensitivity_sobol.rst",
            category=REPORT_BEYOND,
            subcategory="5 References: global sensitivity",
        ),
        convergence_csv=f"{TABLES}/sensitivity_sobol_convergence.csv",
        convergence_md=report(
            f"{TABLES}/sensitivity_sobol_convergence.md",
            caption="../report/sensitivity_convergence.rst",
            category=REPORT_BEYOND,
            subcategory="5 References: global sensitivity",
        ),
    log:
        f"{LOGS}/sobol_tables.log",
    benchmark:
        f"{BENCHMARKS}/sobol_tables.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.sensitivity:sobol_tables",
    script:
        "../scripts/call.py"


rule sobol_heatmap:
    input:
        sobol=rules.sobol_tables.output.csv,
    output:
        figure=report(
            f"{REFERENCES}/sobol_{{prior}}.png",
            caption="../report/sensitivity_heatmap.rst",
            category=REPORT_BEYOND,
            subcategory="5 References: global sensitivity",
        ),
    log:
        f"{LOGS}/sobol_heatmap/{{prior}}.log",
    benchmark:
        f"{BENCHMARKS}/sobol_heatmap/{{prior}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.reference_figures:sobol_heatmap",
        prior=lambda w: w.prior,
    script:
        "../scripts/call.py"


rule sensitivity_identifiability:
    input:
        sobol=rules.sobol_tables.output.csv,
        local=f"{NET_TABLES}/structural_local_identifiability.csv",
    output:
        csv=f"{NET_TABLES}/sensitivity_identifiability.csv",
        md=report(
            f"{NET_TABLES}/sensitivity_identifiability.md",
            caption="../report/sensitivity_identifiability.rst",
            category=REPORT_BEYOND,
            subcategory=f"5 References: global sensitivity{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/sensitivity_identifiability.log",
    benchmark:
        f"{NET_BENCHMARKS}/sensitivity_identifiability.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.sensitivity:sensitivity_identifiability",
        prior="structural",
        influence_threshold=REF["sobol"]["influence_threshold"],
        nonidentifiable_share=config["calibration"]["nonidentifiable_share"],
        spread_threshold=REF["sobol"]["spread_threshold"],
    script:
        "../scripts/call.py"


rule reference_cases:
    input:
        validation=f"{DATA}/ehr/validation.parquet",
        patients=rules.ehr_patients.output.patients,
    output:
        cases=f"{REFERENCES}/cases.csv",
    log:
        f"{LOGS}/reference_cases.log",
    benchmark:
        f"{BENCHMARKS}/reference_cases.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.references:reference_cases",
        n_simulated=REF["mcmc"]["n_simulated"],
        n_patients=REF["mcmc"]["n_patients"],
        calibration_n_cases=config["calibration"]["n_cases"],
        noise_level=REF["noise_level"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule reference_mcmc:
    input:
        cases=rules.reference_cases.output.cases,
    output:
        chain=f"{REFERENCES}/mcmc/{{case}}.npz",
    log:
        f"{LOGS}/reference_mcmc/{{case}}.log",
    benchmark:
        f"{BENCHMARKS}/reference_mcmc/{{case}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        function="cvsim6.studies.references:reference_mcmc",
        case=lambda w: w.case,
        prior=config["data"]["studies"]["ehr"]["prior"],
        simulator=config["simulator"],
        noise_level=REF["noise_level"],
        walkers=REF["mcmc"]["walkers"],
        start_prior_draws=REF["mcmc"]["start_prior_draws"],
        start_iterations=REF["mcmc"]["start_iterations"],
        min_steps=REF["mcmc"]["min_steps"],
        max_steps=REF["mcmc"]["max_steps"],
        check_every=REF["mcmc"]["check_every"],
        rhat_max=REF["mcmc"]["rhat_max"],
        ess_min=REF["mcmc"]["ess_min"],
        keep=REF["mcmc"]["keep"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule reference_diagnostics:
    input:
        chains=expand(rules.reference_mcmc.output.chain, case=REF_CASES),
    output:
        csv=f"{TABLES}/reference_posterior_diagnostics.csv",
        md=report(
            f"{TABLES}/reference_posterior_diagnostics.md",
            caption="../report/reference_diagnostics.rst",
            category=REPORT_BEYOND,
            subcategory="6 References: MCMC posteriors",
        ),
    log:
        f"{LOGS}/reference_diagnostics.log",
    benchmark:
        f"{BENCHMARKS}/reference_diagnostics.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.references:reference_diagnostics",
        rhat_max=REF["mcmc"]["rhat_max"],
        ess_min=REF["mcmc"]["ess_min"],
    script:
        "../scripts/call.py"


rule reference_comparison:
    input:
        cases=rules.reference_cases.output.cases,
        chains=expand(rules.reference_mcmc.output.chain, case=REF_CASES),
        calibration_samples=f"{CALIBRATION}/samples_delta{REF_DELTA}.npz",
        invaert_predictions=f"{NET_EHR}/predictions_delta{REF_DELTA}.parquet",
        npe_predictions=f"{NET_EHR}/npe_predictions_delta{REF_DELTA}.parquet",
    output:
        csv=f"{NET_TABLES}/reference_posteriors.csv",
        md=report(
            f"{NET_TABLES}/reference_posteriors.md",
            caption="../report/reference_posteriors.rst",
            category=REPORT_BEYOND,
            subcategory=f"6 References: MCMC posteriors{NET_MARK}",
        ),
        parameters_csv=f"{NET_TABLES}/reference_posteriors_parameters.csv",
        figure_data=f"{NET_REFERENCES}/marginals.npz",
    log:
        f"{NET_LOGS}/reference_comparison.log",
    benchmark:
        f"{NET_BENCHMARKS}/reference_comparison.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.references:reference_comparison",
        prior=config["data"]["studies"]["ehr"]["prior"],
        figure_cases=REF["figure_cases"],
        c2st_folds=REF["c2st_folds"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule reference_marginals:
    input:
        figure_data=rules.reference_comparison.output.figure_data,
    output:
        figure=report(
            f"{NET_REFERENCES}/marginals_{{case}}.png",
            caption="../report/reference_marginals.rst",
            category=REPORT_BEYOND,
            subcategory=f"6 References: MCMC posteriors{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/reference_marginals/{{case}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/reference_marginals/{{case}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.reporting.reference_figures:reference_marginals",
        case=lambda w: w.case,
    script:
        "../scripts/call.py"


rule references:
    input:
        rules.sobol_tables.output,
        expand(rules.sobol_heatmap.output.figure, prior=REF_PRIORS),
        rules.sensitivity_identifiability.output,
        rules.reference_diagnostics.output,
        rules.reference_comparison.output,
        expand(
            rules.reference_marginals.output.figure,
            case=[c for c in REF["figure_cases"] if c in REF_CASES],
        ),
