# The EHR dataset (section 3.4): its file (a configured local path, or downloaded
# from its public origin into resources/), and the patients selected for inversion.

EHR = f"{RESULTS}/ehr"


rule download_ehr:
    output:
        output="resources/EHR_dataset.csv",
    params:
        function="cvsim6.ehr:download_ehr",
        url=config["ehr_data"]["url"],
        sha256=config["ehr_data"]["sha256"],
    log:
        f"{LOGS}/download_ehr.log",
    benchmark:
        f"{BENCHMARKS}/download_ehr.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/cvsim6.yaml"
    script:
        "../scripts/call.py"


rule ehr_patients:
    input:
        code=package_code("ehr", "tables"),
        csv=ehr_csv,
    output:
        patients=f"{EHR}/patients.csv",
        counts_csv=f"{EHR}/output_counts.csv",
        counts_md=f"{EHR}/output_counts.md",
    params:
        function="cvsim6.ehr:write_patient_selection",
    log:
        f"{LOGS}/ehr_patients.log",
    benchmark:
        f"{BENCHMARKS}/ehr_patients.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/cvsim6.yaml"
    script:
        "../scripts/call.py"
