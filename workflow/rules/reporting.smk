"""The paper's tables and figures, and the target rules `tables`, `figures`, `analyses` and `all`
(`tables` and `figures` include those of the analyses in the config)."""


rule make_tables:
    input:
        summaries=runs(),
        unseen=runs(name="unseen.json"),
        baselines=baselines(),
        ood=OOD_SOURCES if OOD else [],
        code=code("tables"),
    output:
        [f for name in TABLES for f in table_files(name, f"../report/{name}.rst")],
    log:
        log_file("tables"),
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
        summaries=runs(),
        logs=runs(name="log.csv"),
        ood=OOD_SOURCES if OOD else [],
        ood_particles=[f.replace(".json", ".npz") for f in OOD_SOURCES] if OOD else [],
        datapoints=prepared(ood_ids()) if OOD else [],
        code=code("figures"),
    output:
        runs=[
            f
            for level in IDENT["levels"]
            for f in figure_files(f"runs_L{level}", "../report/runs.rst")
        ],
        ood=[
            f
            for kind in ("heightmaps", "particles", "frames")
            for i in (ood_ids() if OOD else [])
            for f in figure_files(f"{kind}_{i}", f"../report/{kind}.rst")
        ],
        uncertainty=(
            figure_files("uncertainty", "../report/uncertainty_figure.rst")
            if UNCERTAINTY
            else []
        ),
    log:
        log_file("figures"),
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
