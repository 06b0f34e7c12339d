"""Identification runs (SPEC §6): one job per (level, loss, dataset, seed), and the hand-picked baseline."""


def truth_file():
    return [f"{RAW}/truth.json"] if "twin" in config else []


rule identify:
    output:
        summary=f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}/summary.json",
        log=f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}/log.csv",
    input:
        training=lambda w: prepared(training_ids(w.level, w.dataset)),
        validation=lambda w: prepared(validation_ids(w.level)),
        truth=truth_file(),
        code=library("identification", "simulation", "losses", "optim", "parameters", "datapoint"),
    params:
        iterations=IDENT["iterations"],
        initial=IDENT.get("initial", "random"),
        simulator=simulator_params(),
    threads: 1
    resources:
        mem_mb=3000,
        runtime=720,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    log:
        f"logs/{config['dataset']}/identify/L{{level}}_{{loss}}_{{dataset}}_seed{{seed}}.log",
    script:
        "../scripts/identify.py"


rule validate_hand_picked:
    output:
        f"{RESULTS}/validation/L{{level}}/hand-picked.json",
    input:
        validation=lambda w: prepared(validation_ids(w.level)),
        code=library("identification", "simulation", "losses", "parameters", "datapoint"),
    params:
        simulator=simulator_params(),
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    log:
        f"logs/{config['dataset']}/validate/L{{level}}_hand-picked.log",
    script:
        "../scripts/validate_hand_picked.py"
