"""The paper's tables and figures, and the target rules `tables`, `figures` and `all`."""

TABLES = ["motions", "parameters", "best_params", "ood_heightmap", "recovery_error"]
OOD_SOURCES = [f"{RESULTS}/ood/hand-picked.json"] + expand(f"{RESULTS}/ood/{{loss}}/{{dataset}}.json",
                                                           loss=IDENT["losses"], dataset=IDENT["datasets"])


def table_report(name, suffix):
    path = f"results/tables/{name}.{suffix}"
    return report(path, caption=f"../report/{name}.rst", category="Tables") if suffix == "csv" else path


rule make_tables:
    output:
        [table_report(name, suffix) for name in TABLES for suffix in ("csv", "md", "tex")],
    input:
        summaries=runs(),
        hand_picked=expand(f"{RESULTS}/validation/L{{level}}/hand-picked.json", level=IDENT["levels"]),
        ood=OOD_SOURCES if 2 in IDENT["levels"] else [],
        code=library("reporting", "motions", "parameters"),
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    log:
        "logs/tables.log",
    script:
        "../scripts/tables.py"


rule make_figures:
    output:
        runs=[report(f"results/figures/runs_L{level}.{suffix}", caption="../report/runs.rst", category="Figures")
              for level in IDENT["levels"] for suffix in ("png", "pdf")],
        ood=[report(f"results/figures/{kind}_{i}.{suffix}", caption=f"../report/{kind}.rst", category="Figures")
             for kind in ("heightmaps", "particles") for i in (ood_ids() if 2 in IDENT["levels"] else [])
             for suffix in ("png", "pdf")],
    input:
        logs=[s.replace("summary.json", "log.csv") for s in runs()],
        ood=OOD_SOURCES if 2 in IDENT["levels"] else [],
        ood_particles=[f.replace(".json", ".npz") for f in OOD_SOURCES] if 2 in IDENT["levels"] else [],
        datapoints=prepared(ood_ids()) if 2 in IDENT["levels"] else [],
        code=library("reporting", "heightmap"),
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    log:
        "logs/figures.log",
    script:
        "../scripts/figures.py"


rule tables:
    input:
        rules.make_tables.output,
    localrule: True


rule figures:
    input:
        rules.make_figures.output,
    localrule: True


rule all:
    input:
        rules.make_tables.output,
        rules.make_figures.output,
    default_target: True
    localrule: True
