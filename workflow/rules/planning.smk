"""Appendix B (SPEC §7.8): greedy planning with the configured parameters from the before state of the
clay twin's first out-of-distribution flattening towards the height map of its captured after state.
"""

if "planning" in ANALYSES:
    PLANNING = ANALYSES["planning"]
    try:
        PLANNING_START = dpsi_datasets.planning_start(TABLE)
    except ValueError as err:
        raise WorkflowError(f"analyses.planning cannot run: {err}")

    rule greedy_plan:
        input:
            datapoint=prepared([PLANNING_START]),
            parameters=parameter_source_inputs(PLANNING["parameters"]),
            code=code("plan"),
        output:
            record=f"{RESULTS}/planning/plan.json",
            arrays=f"{RESULTS}/planning/plan.npz",
        log:
            log_file("planning/plan"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            runtime=10 + 15 * PLANNING["actions"],
            gres=GPU_GRES,
        params:
            simulator=simulator_params(),
            planning=PLANNING,
        script:
            "../scripts/plan.py"

    rule planning_report:
        input:
            record=rules.greedy_plan.output.record,
            arrays=rules.greedy_plan.output.arrays,
            code=code("plan_report"),
        output:
            table=table_files("planning", "../report/planning.rst"),
            figure=figure_files("planning", "../report/planning_figure.rst"),
        log:
            log_file("planning_report"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        script:
            "../scripts/plan_report.py"

    ANALYSIS_TABLES += rules.planning_report.output.table
    ANALYSIS_FIGURES += rules.planning_report.output.figure
