# Tables 1 and 2 of the paper: model inputs and outputs, from cvsim6.registry.


rule input_parameter_table:
    output:
        csv=f"{TABLES}/input_parameters.csv",
        md=report(
            f"{TABLES}/input_parameters.md",
            caption="../report/input_parameters.rst",
            category=REPORT_MODEL,
        ),
    log:
        f"{LOGS}/input_parameter_table.log",
    benchmark:
        f"{BENCHMARKS}/input_parameter_table.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.reporting.tables:write_input_table",
    script:
        "../scripts/call.py"


rule output_parameter_table:
    output:
        csv=f"{TABLES}/output_parameters.csv",
        md=report(
            f"{TABLES}/output_parameters.md",
            caption="../report/output_parameters.rst",
            category=REPORT_MODEL,
        ),
    log:
        f"{LOGS}/output_parameter_table.log",
    benchmark:
        f"{BENCHMARKS}/output_parameter_table.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.reporting.tables:write_output_table",
    script:
        "../scripts/call.py"
