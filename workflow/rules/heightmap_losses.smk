"""Appendix A (SPEC §7.7): level-1 runs optimising the height-map distance, its negation and point-cloud
losses, compared by their validation metrics."""

if "heightmap_losses" in ANALYSES:
    HEIGHTMAP_LOSSES = ANALYSES["heightmap_losses"]
    HEIGHTMAP_LOSSES_RUNS = analysis_runs(
        "heightmap_losses",
        level=1,
        losses=HEIGHTMAP_LOSSES["losses"],
        datasets=HEIGHTMAP_LOSSES["datasets"],
        seeds=HEIGHTMAP_LOSSES["seeds"],
    )

    rule heightmap_losses_results:
        input:
            summaries=run_files(HEIGHTMAP_LOSSES_RUNS, "summary.json"),
            logs=run_files(HEIGHTMAP_LOSSES_RUNS, "log.csv"),
            code=code("heightmap_losses"),
        output:
            table=table_files("heightmap_losses", "../report/heightmap_losses.rst"),
            figure=figure_files(
                "heightmap_losses", "../report/heightmap_losses_runs.rst"
            ),
        log:
            log_file("heightmap_losses"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        script:
            "../scripts/heightmap_losses.py"

    ANALYSIS_TABLES += rules.heightmap_losses_results.output.table
    ANALYSIS_FIGURES += rules.heightmap_losses_results.output.figure
