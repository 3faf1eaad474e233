# The EHR dataset (section 3.4): its file (a configured local path, or downloaded
# from its public origin into resources/), and the patients selected for inversion.

#: The patient selection (independent of the networks).
EHR = f"{RESULTS}/ehr"
#: Inversions, tables and figures made with the networks in use.
NET_EHR = f"{NET}/ehr"


rule download_ehr:
    output:
        output="resources/EHR_dataset.csv",
    log:
        f"{LOGS}/download_ehr.log",
    benchmark:
        f"{BENCHMARKS}/download_ehr.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.data.ehr:download_ehr",
        url=config["ehr_data"]["url"],
        sha256=config["ehr_data"]["sha256"],
    script:
        "../scripts/call.py"


rule ehr_patients:
    input:
        csv=ehr_csv,
    output:
        patients=f"{EHR}/patients.csv",
        counts_csv=f"{EHR}/output_counts.csv",
        counts_md=report(
            f"{EHR}/output_counts.md",
            caption="../report/ehr_output_counts.rst",
            category=REPORT_STUDY["ehr"],
            subcategory="1 Data",
        ),
    log:
        f"{LOGS}/ehr_patients.log",
    benchmark:
        f"{BENCHMARKS}/ehr_patients.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.data.ehr:write_patient_selection",
    script:
        "../scripts/call.py"


rule invert_ehr_patients:
    input:
        patients=rules.ehr_patients.output.patients,
        flow=f"{MODELS}/ehr/flow_delta{{delta}}.pt",
        encoder_decoder=f"{MODELS}/ehr/encoder_decoder_delta{{delta}}.pt",
        emulator=f"{MODELS}/ehr/emulator.pt",
        reference=f"{DATA}/ehr/validation.parquet",
    output:
        predictions=f"{NET_EHR}/predictions_delta{{delta}}.parquet",
    log:
        f"{NET_LOGS}/invert_ehr_patients/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/invert_ehr_patients/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        function="cvsim6.studies.ehr:invert_ehr_patients",
        noise_level=lambda w: float(w.delta),
        n_latent=config["ehr_study"]["n_latent"],
        n_flow_samples=config["ehr_study"]["n_flow_samples"],
        n_reference=config["ehr_study"]["n_reference"],
        reference_flow_samples=config["ehr_study"]["reference_flow_samples"],
        corrector_steps=config["ehr_study"]["corrector_steps"],
        seed=config["seed"],
    script:
        "../scripts/call.py"


rule ehr_error_table:
    input:
        patients=rules.ehr_patients.output.patients,
        predictions=expand(
            f"{NET_EHR}/predictions_delta{{delta}}.parquet",
            delta=noise_tags("ehr"),
        ),
    output:
        csv=f"{NET_TABLES}/ehr_error_per_output.csv",
        md=report(
            f"{NET_TABLES}/ehr_error_per_output.md",
            caption="../report/ehr_error_table.rst",
            category=REPORT_STUDY["ehr"],
            subcategory=f"3 Patient inversion{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/ehr_error_table.log",
    benchmark:
        f"{NET_BENCHMARKS}/ehr_error_table.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.studies.ehr:ehr_error_table",
    script:
        "../scripts/call.py"


rule ehr_ood_table:
    input:
        predictions=f"{NET_EHR}/predictions_delta{{delta}}.parquet",
    output:
        csv=f"{NET_TABLES}/ehr_ood_delta{{delta}}.csv",
        md=report(
            f"{NET_TABLES}/ehr_ood_delta{{delta}}.md",
            caption="../report/ehr_ood_table.rst",
            category=REPORT_BEYOND,
            subcategory=f"2 EHR out-of-distribution score{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/ehr_ood_table/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/ehr_ood_table/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        function="cvsim6.studies.ehr:ood_table",
    script:
        "../scripts/call.py"


rule ehr_patient_figure:
    input:
        patients=rules.ehr_patients.output.patients,
        predictions=f"{NET_EHR}/predictions_delta{{delta}}.parquet",
    output:
        figure=report(
            f"{NET_EHR}/patient_predictions_delta{{delta}}.png",
            caption="../report/ehr_patient_figure.rst",
            category=REPORT_STUDY["ehr"],
            subcategory=f"3 Patient inversion{NET_MARK}",
        ),
    log:
        f"{NET_LOGS}/ehr_patient_figure/delta{{delta}}.log",
    benchmark:
        f"{NET_BENCHMARKS}/ehr_patient_figure/delta{{delta}}.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        function="cvsim6.reporting.ehr_figures:ehr_patient_figure",
    script:
        "../scripts/call.py"
