# The reproduction scorecard: every headline number of the paper beside ours, for the
# networks in use and, when its results exist, for the other source side by side.


rule reproduction_scorecard:
    input:
        **scorecard_files(NETWORK_SOURCE),
    output:
        csv=f"{RESULTS}/report/reproduction.csv",
        md=report(
            f"{RESULTS}/report/reproduction.md",
            caption="../report/reproduction.rst",
            category=REPORT_SCORECARD,
        ),
    log:
        f"{LOGS}/reproduction_scorecard.log",
    benchmark:
        f"{BENCHMARKS}/reproduction_scorecard.tsv"
    conda:
        "../envs/cvsim6.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        function="cvsim6.reporting.scorecard:write_scorecard",
        source=NETWORK_SOURCE,
        other_sources={
            s: scorecard_files(s) for s in NETWORK_RESULTS if s != NETWORK_SOURCE
        },
        seed_spread=optional_text(SEED_SCORECARD),
    script:
        "../scripts/call.py"
