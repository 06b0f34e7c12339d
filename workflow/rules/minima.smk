"""Local minima (SPEC §7.5): level-1 runs from random initial values (one per seed) against runs from
the hand-picked values. The hand-picked start ignores the seed and the optimisation is deterministic,
so its run is made once per dataset (with the first seed) and stands for every seed."""

if "minima" in ANALYSES:
    MINIMA = ANALYSES["minima"]
    MINIMA_RUNS = [
        *analysis_runs(
            "minima",
            level=1,
            losses=[MINIMA["loss"]],
            datasets=MINIMA["datasets"],
            seeds=MINIMA["seeds"],
        ),
        *analysis_runs(
            "minima",
            level=1,
            losses=[MINIMA["loss"]],
            datasets=MINIMA["datasets"],
            seeds=MINIMA["seeds"][:1],
            starts=["hand-picked"],
        ),
    ]

    rule minima_results:
        input:
            summaries=run_files(MINIMA_RUNS, "summary.json"),
            logs=run_files(MINIMA_RUNS, "log.csv"),
            code=code("minima"),
        output:
            table=table_files("minima", "../report/minima.rst"),
            figure=figure_files("minima", "../report/minima_runs.rst"),
        log:
            log_file("minima"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        script:
            "../scripts/minima.py"

    ANALYSIS_TABLES += rules.minima_results.output.table
    ANALYSIS_FIGURES += rules.minima_results.output.figure
