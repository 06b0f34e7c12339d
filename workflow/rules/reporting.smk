"""The paper's tables and figures, and the target rules `tables`, `figures`, `analyses` and `all`
(`tables` and `figures` include those of the analyses in the config)."""


rule make_tables:
    input:
        summaries=runs(),
        hand_picked=expand(
            f"{RESULTS}/validation/L{{level}}/hand-picked.json", level=IDENT["levels"]
        ),
        ood=OOD_SOURCES if 2 in IDENT["levels"] else [],
        code=library("reporting", "motions", "parameters"),
    output:
        [
            report(
                f"results/tables/{name}.csv",
                caption=f"../report/{name}.rst",
                category="Tables",
            )
            for name in TABLES
        ]
        + [
            f"results/tables/{name}.{suffix}"
            for name in TABLES
            for suffix in ("md", "tex")
        ],
    log:
        "logs/tables.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    script:
        "../scripts/tables.py"


rule make_figures:
    input:
        logs=[s.replace("summary.json", "log.csv") for s in runs()],
        ood=OOD_SOURCES if 2 in IDENT["levels"] else [],
        ood_particles=(
            [f.replace(".json", ".npz") for f in OOD_SOURCES]
            if 2 in IDENT["levels"]
            else []
        ),
        datapoints=prepared(ood_ids()) if 2 in IDENT["levels"] else [],
        code=library("reporting", "heightmap"),
    output:
        runs=[
            report(
                f"results/figures/runs_L{level}.{suffix}",
                caption="../report/runs.rst",
                category="Figures",
            )
            for level in IDENT["levels"]
            for suffix in ("png", "pdf")
        ],
        ood=[
            report(
                f"results/figures/{kind}_{i}.{suffix}",
                caption=f"../report/{kind}.rst",
                category="Figures",
            )
            for kind in ("heightmaps", "particles", "frames")
            for i in (ood_ids() if 2 in IDENT["levels"] else [])
            for suffix in ("png", "pdf")
        ],
    log:
        "logs/figures.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/figures.py"


rule tables:
    input:
        rules.make_tables.output,
        ANALYSIS_TABLES,
    localrule: True


rule figures:
    input:
        rules.make_figures.output,
        ANALYSIS_FIGURES,
    localrule: True


rule analyses:
    input:
        ANALYSIS_TABLES,
        ANALYSIS_FIGURES,
    localrule: True


rule all:
    default_target: True
    input:
        rules.tables.input,
        rules.figures.input,
    localrule: True
