"""Identification runs (SPEC §6): one job per (level, loss, dataset, seed), and the hand-picked baseline."""


rule identify:
    input:
        training=lambda w: prepared(training_ids(w.level, w.dataset)),
        validation=lambda w: prepared(validation_ids(w.level)),
        truth=truth_file(),
        code=library(
            "identification",
            "simulation",
            "losses",
            "optim",
            "parameters",
            "datapoint",
        ),
    output:
        summary=f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}/summary.json",
        log=f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}/log.csv",
    log:
        f"logs/{config['dataset']}/identify/L{{level}}_{{loss}}_{{dataset}}_seed{{seed}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=720,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    params:
        iterations=IDENT["iterations"],
        initial=IDENT.get("initial", "random"),
        simulator=simulator_params(),
    script:
        "../scripts/identify.py"


rule validate_hand_picked:
    input:
        validation=lambda w: prepared(validation_ids(w.level)),
        code=library(
            "identification", "simulation", "losses", "parameters", "datapoint"
        ),
    output:
        f"{RESULTS}/validation/L{{level}}/hand-picked.json",
    log:
        f"logs/{config['dataset']}/validate/L{{level}}_hand-picked.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/validate_hand_picked.py"
