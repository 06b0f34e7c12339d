"""Identification runs (SPEC §6): one job per (level, loss, dataset, seed), and the hand-picked baseline.

The analyses that are variations of identification runs (materials, minima, heightmap_losses) declare
their runs with `analysis_runs` and get them from `identify_analysis`, the same job as `identify`
with the material and the initial values as wildcards, under <output root>/<dataset>/<analysis>/.
"""


include: "analysis_runs.smk"


RUN_ANALYSES = [a for a in ("materials", "minima", "heightmap_losses") if a in ANALYSES]


rule identify:
    input:
        training=lambda w: prepared(training_ids(w.level, w.dataset)),
        validation=lambda w: prepared(validation_ids(w.level, w.dataset)),
        truth=truth_file(),
        code=code("identify"),
    output:
        summary=f"{MAIN_RUN}/summary.json",
        log=f"{MAIN_RUN}/log.csv",
    log:
        log_file("identify/L{level}_{loss}_{dataset}_seed{seed}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=lambda w: run_minutes(
            training_ids(w.level, w.dataset) + validation_ids(w.level, w.dataset),
            IDENT["iterations"],
        ),
        gres=GPU_GRES,
    params:
        iterations=IDENT["iterations"],
        initial=IDENT.get("initial", "random"),
        known=IDENT.get("known", {}),
        select="validation",
        uncertainty=IDENT.get("uncertainty", False),
        simulator=simulator_params(),
    script:
        "../scripts/identify.py"


if RUN_ANALYSES:

    use rule identify as identify_analysis with:
        input:
            training=lambda w: prepared(
                dpsi_datasets.select(TABLE, int(w.level), w.dataset, w.material)
            ),
            validation=lambda w: prepared(
                dpsi_datasets.validation(TABLE, int(w.level), w.material)
            ),
            # the script compares with the truth of clay: other materials get none in their summary
            truth=lambda w: truth_file() if w.material == "clay" else [],
            code=code("identify"),
        output:
            summary=f"{ANALYSIS_RUN}/summary.json",
            log=f"{ANALYSIS_RUN}/log.csv",
        log:
            log_file(
                "{analysis}/{material}_{start}_L{level}_{loss}_{dataset}_seed{seed}"
            ),
        wildcard_constraints:
            analysis="|".join(RUN_ANALYSES),
            material="[a-z]+",
            start="random|hand-picked",
        resources:
            mem_mb=3000,
            runtime=lambda w: run_minutes(
                dpsi_datasets.select(TABLE, int(w.level), w.dataset, w.material)
                + dpsi_datasets.validation(TABLE, int(w.level), w.material),
                ANALYSES[w.analysis]["iterations"],
            ),
            gres=GPU_GRES,
        params:
            iterations=lambda w: ANALYSES[w.analysis]["iterations"],
            initial=lambda w: w.start,
            known={},
            select="validation",
            uncertainty=False,
            simulator=simulator_params(),


rule baseline:
    input:
        datapoint=lambda w: prepared([w.id])[0],
        code=code("baseline"),
    output:
        f"{RESULTS}/baselines/L{{level}}/{{id}}.json",
    log:
        log_file("baseline/L{level}_{id}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
        gres=GPU_GRES,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/baseline.py"


rule unseen:
    input:
        summary=f"{MAIN_RUN}/summary.json",
        datapoints=lambda w: prepared(unseen_ids(w.level, w.dataset)),
        code=code("unseen"),
    output:
        f"{MAIN_RUN}/unseen.json",
    log:
        log_file("unseen/L{level}_{loss}_{dataset}_seed{seed}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
        gres=GPU_GRES,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/unseen.py"
