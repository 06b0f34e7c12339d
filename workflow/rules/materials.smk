"""Other materials (SPEC §7.4): the level-2 runs of each synthetic material on one dataset, their
recovered parameters against the twin's ground truth, and the runs over the iterations.
"""

if "materials" in ANALYSES:
    MATERIALS = ANALYSES["materials"]
    if "twin" not in config:
        raise WorkflowError(
            "analysis materials compares with the ground truth of a synthetic twin: add a `twin` "
            "section with groups of the materials to the config"
        )
    MATERIALS_RUNS = analysis_runs(
        "materials",
        level=2,
        losses=[MATERIALS["loss"]],
        datasets=[MATERIALS["dataset"]],
        seeds=MATERIALS["seeds"],
        materials=MATERIALS["materials"],
    )
    MATERIALS_VALIDATION = sorted(
        {
            TABLE.set_index("id").motion[i]
            for material in MATERIALS["materials"]
            for i in dpsi_datasets.validation(TABLE, 2, material)
        }
    )
    ANALYSIS_TABLES += [f"results/tables/materials.{s}" for s in ("csv", "md", "tex")]
    ANALYSIS_FIGURES += [f"results/figures/materials.{s}" for s in ("png", "pdf")]

    rule materials_results:
        input:
            summaries=run_files(MATERIALS_RUNS, "summary.json"),
            logs=run_files(MATERIALS_RUNS, "log.csv"),
            truth=truth_file(),
            code=library("reporting", "parameter_sources", "parameters", "twin"),
        output:
            table=report(
                "results/tables/materials.csv",
                caption="../report/materials.rst",
                category="Tables",
            ),
            other_tables=multiext("results/tables/materials", ".md", ".tex"),
            png=report(
                "results/figures/materials.png",
                caption="../report/materials_runs.rst",
                category="Figures",
            ),
            pdf="results/figures/materials.pdf",
        log:
            "logs/materials.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        params:
            labels=list(MATERIALS_RUNS.values()),
            materials=MATERIALS["materials"],
            validation=MATERIALS_VALIDATION,
        script:
            "../scripts/materials.py"
