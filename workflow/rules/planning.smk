"""Appendix B (SPEC §7.8): greedy planning with the configured parameters from the before state of the
clay twin's first out-of-distribution flattening towards the height map of its captured after state.
"""

from dpsi import planning as dpsi_planning

if "planning" in ANALYSES:
    PLANNING = ANALYSES["planning"]
    try:
        PLANNING_START = dpsi_planning.start_datapoint(TABLE)
    except ValueError as err:
        raise WorkflowError(f"analyses.planning cannot run: {err}")
    PLANNING_FILES = [f"results/tables/planning.{s}" for s in ("csv", "md", "tex")] + [
        f"results/figures/planning.{s}" for s in ("png", "pdf")
    ]

    rule greedy_plan:
        input:
            datapoint=prepared([PLANNING_START]),
            parameters=parameter_source_inputs(PLANNING["parameters"]),
            code=library(
                "planning",
                "simulation",
                "parameter_sources",
                "parameters",
                "motions",
                "effectors",
                "heightmap",
                "datapoint",
                "prepare",
                "losses",
            ),
        output:
            record=f"{RESULTS}/planning/plan.json",
            arrays=f"{RESULTS}/planning/plan.npz",
        log:
            f"logs/{config['dataset']}/planning/plan.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            runtime=10 + 15 * PLANNING["actions"],
            gpu=1 if config.get("taichi_arch") == "cuda" else 0,
        params:
            simulator=simulator_params(),
            planning=PLANNING,
        script:
            "../scripts/plan.py"

    rule planning_report:
        input:
            record=rules.greedy_plan.output.record,
            arrays=rules.greedy_plan.output.arrays,
            code=library("reporting", "planning", "heightmap", "motions"),
        output:
            table=report(
                PLANNING_FILES[0], caption="../report/planning.rst", category="Tables"
            ),
            table_formats=PLANNING_FILES[1:3],
            figure=report(
                PLANNING_FILES[3],
                caption="../report/planning_figure.rst",
                category="Figures",
            ),
            figure_pdf=PLANNING_FILES[4],
        log:
            "logs/planning_report.log",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        script:
            "../scripts/plan_report.py"

    ANALYSIS_TABLES += PLANNING_FILES[:3]
    ANALYSIS_FIGURES += PLANNING_FILES[3:]
