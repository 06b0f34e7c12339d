"""Computation cost table (SPEC §7.6): one timing job per (motion, density), each measuring in a child
process of its own so that its peak memory is the measurement's own, then the table. Timing jobs ask for
one unit of the custom resource `timing`: run with `--resources timing=1` so that no two of them run at
the same time.
"""

if "cost" in ANALYSES:
    COST = ANALYSES["cost"]
    COST_RECORDS = [
        f"{OUT}/cost/{motion}/density{density:g}.json"
        for motion in COST["motions"]
        for density in COST["densities"]
    ]

    rule cost_measure:
        input:
            code=code("cost_measure"),
        output:
            f"{OUT}/cost/{{motion}}/density{{density}}.json",
        log:
            log_file("cost/{motion}_density{density}"),
        wildcard_constraints:
            motion="|".join(COST["motions"]),
            density=r"[0-9.]+(e[+-]?[0-9]+)?",
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=4000,
            runtime=30 + 5 * COST["measured_iterations"],
            gres=GPU_GRES,
            timing=1,
        params:
            measured_iterations=COST["measured_iterations"],
            simulator=simulator_params(),
        script:
            "../scripts/cost_measure.py"

    rule cost_table:
        input:
            records=COST_RECORDS,
            code=code("cost_table"),
        output:
            table=table_files("cost", "../report/cost.rst"),
        log:
            log_file("cost/table"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            iterations=COST["iterations"],
        script:
            "../scripts/cost_table.py"

    ANALYSIS_TABLES += rules.cost_table.output.table
