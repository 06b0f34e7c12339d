"""Resolution study (issue 10): the clay truth's poking and poking-shifting simulated on one lump at each
configured grid cell dx, with the particle density scaled to keep two particles per cell per axis, and
the final height maps compared with the finest run's. One job runs every dx, each in a child process of
its own; it times forward passes, so it takes one unit of the custom resource `timing` like the cost
analysis (run with `--resources timing=1`)."""

if "convergence" in ANALYSES:
    CONVERGENCE = ANALYSES["convergence"]
    # minutes: work grows as (1/dx)⁴ (particles as (1/dx)³, substeps as 1/dx); ~6 min per motion at 3 mm;
    # memory: 3 GiB at 3 mm, ~12 GiB at 2 mm (the per-substep fields, docs/benchmarks.md)
    CONVERGENCE_MINUTES = 10 + sum(
        6 * (3.0 / dx) ** 4 * len(CONVERGENCE["motions"]) for dx in CONVERGENCE["dx_mm"]
    )

    rule convergence_table:
        input:
            code=code("convergence"),
        output:
            table=table_files("convergence", "../report/convergence.rst"),
        log:
            log_file("convergence"),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=16000 if min(CONVERGENCE["dx_mm"]) < 3 else 4000,
            runtime=CONVERGENCE_MINUTES,
            gres=GPU_GRES,
            timing=1,
        params:
            motions=CONVERGENCE["motions"],
            dx_mm=CONVERGENCE["dx_mm"],
            simulator={
                k: v
                for k, v in simulator_params().items()
                if k not in ("dx", "max_particles")
            },
        script:
            "../scripts/convergence.py"

    ANALYSIS_TABLES += rules.convergence_table.output.table
