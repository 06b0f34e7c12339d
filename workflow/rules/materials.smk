"""Other materials (SPEC §7.4): the level-2 runs of each synthetic material on one dataset, their
recovered parameters against the twin's ground truth, and the runs over the iterations.
"""

if "materials" in ANALYSES:
    MATERIALS = ANALYSES["materials"]
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

    rule materials_results:
        input:
            summaries=run_files(MATERIALS_RUNS, "summary.json"),
            logs=run_files(MATERIALS_RUNS, "log.csv"),
            truth=truth_file(),
            code=code("materials"),
        output:
            table=table_files("materials", "../report/materials.rst"),
            figure=figure_files("materials", "../report/materials_runs.rst"),
        log:
            log_file("materials"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=10,
        params:
            materials=MATERIALS["materials"],
            validation=MATERIALS_VALIDATION,
        script:
            "../scripts/materials.py"

    ANALYSIS_TABLES += rules.materials_results.output.table
    ANALYSIS_FIGURES += rules.materials_results.output.figure
