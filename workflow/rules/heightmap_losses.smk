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
    ANALYSIS_TABLES += [
        f"results/tables/heightmap_losses.{s}" for s in ("csv", "md", "tex")
    ]
    ANALYSIS_FIGURES += [
        f"results/figures/heightmap_losses.{s}" for s in ("png", "pdf")
    ]

    rule heightmap_losses_results:
        input:
            summaries=run_files(HEIGHTMAP_LOSSES_RUNS, "summary.json"),
            logs=run_files(HEIGHTMAP_LOSSES_RUNS, "log.csv"),
            code=library("reporting", "parameters"),
        output:
            table=report(
                "results/tables/heightmap_losses.csv",
                caption="../report/heightmap_losses.rst",
                category="Tables",
            ),
            other_tables=multiext("results/tables/heightmap_losses", ".md", ".tex"),
            png=report(
                "results/figures/heightmap_losses.png",
                caption="../report/heightmap_losses_runs.rst",
                category="Figures",
            ),
            pdf="results/figures/heightmap_losses.pdf",
        log:
            "logs/heightmap_losses.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        params:
            labels=list(HEIGHTMAP_LOSSES_RUNS.values()),
        script:
            "../scripts/heightmap_losses.py"
