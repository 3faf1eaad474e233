# The reproduction scorecard: every headline number of the paper beside ours, for the
# networks in use and, when its results exist, for the other source side by side.


def scorecard_files(source):
    """The workflow outputs the scorecard reads for one network source (cvsim6.scorecard.HEADLINE_FILES)."""
    root = NETWORK_RESULTS[source]
    return dict(
        stiffness=f"{STIFFNESS}/sr_extremes.csv",
        structural_emulator=f"{root}/tables/structural_emulator_validation.csv",
        structural_inversion=f"{root}/tables/structural_inversion_errors.csv",
        manifold=f"{root}/tables/structural_manifold_reconstruction.json",
        svd=f"{root}/structural/manifold_svd.json",
        missing=f"{root}/tables/structural_missing_data.json",
        ehr_emulator=f"{root}/training/ehr/emulator_l2_errors.json",
        ehr_errors=f"{root}/tables/ehr_error_per_output.csv",
    )


rule reproduction_scorecard:
    input:
        code=code_for("cvsim6.scorecard:write_scorecard"),
        **scorecard_files(NETWORK_SOURCE),
    output:
        csv=f"{RESULTS}/report/reproduction.csv",
        md=report(
            f"{RESULTS}/report/reproduction.md",
            category="Reproduction scorecard",
            caption="../report/reproduction.rst",
        ),
    params:
        function="cvsim6.scorecard:write_scorecard",
        source=NETWORK_SOURCE,
        other_sources={s: scorecard_files(s) for s in NETWORK_RESULTS if s != NETWORK_SOURCE},
    log:
        f"{LOGS}/reproduction_scorecard.log",
    benchmark:
        f"{BENCHMARKS}/reproduction_scorecard.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/cvsim6.yaml"
    script:
        "../scripts/call.py"
