"""Local minima (SPEC §7.5): level-1 runs from random initial values (one per seed) against runs from
the hand-picked values. The hand-picked start ignores the seed and the optimisation is deterministic,
so its run is made once per dataset (with the first seed) and stands for every seed."""

if "minima" in ANALYSES:
    MINIMA = ANALYSES["minima"]
    MINIMA_RUNS = {
        **analysis_runs(
            "minima",
            level=1,
            losses=[MINIMA["loss"]],
            datasets=MINIMA["datasets"],
            seeds=MINIMA["seeds"],
        ),
        **analysis_runs(
            "minima",
            level=1,
            losses=[MINIMA["loss"]],
            datasets=MINIMA["datasets"],
            seeds=MINIMA["seeds"][:1],
            starts=["hand-picked"],
        ),
    }
    ANALYSIS_TABLES += [f"results/tables/minima.{s}" for s in ("csv", "md", "tex")]
    ANALYSIS_FIGURES += [f"results/figures/minima.{s}" for s in ("png", "pdf")]

    rule minima_results:
        input:
            summaries=run_files(MINIMA_RUNS, "summary.json"),
            logs=run_files(MINIMA_RUNS, "log.csv"),
            code=library("reporting", "parameters"),
        output:
            table=report(
                "results/tables/minima.csv",
                caption="../report/minima.rst",
                category="Tables",
            ),
            other_tables=multiext("results/tables/minima", ".md", ".tex"),
            png=report(
                "results/figures/minima.png",
                caption="../report/minima_runs.rst",
                category="Figures",
            ),
            pdf="results/figures/minima.pdf",
        log:
            "logs/minima.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        params:
            labels=list(MINIMA_RUNS.values()),
        script:
            "../scripts/minima.py"
