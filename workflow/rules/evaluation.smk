"""Out-of-distribution generalisation (SPEC §7.3): the long motions simulated with the best level-2
parameters of each (loss, dataset), and with the hand-picked ones."""


rule ood_identified:
    input:
        summaries=expand(
            f"{RESULTS}/runs/L2/{{{{loss}}}}/{{{{dataset}}}}/seed{{seed}}/summary.json",
            seed=IDENT["seeds"],
        ),
        datapoints=prepared(ood_ids()) if 2 in IDENT["levels"] else [],
        code=library(
            "identification",
            "simulation",
            "losses",
            "parameters",
            "datapoint",
            "reporting/frames",
        ),
    output:
        records=f"{RESULTS}/ood/{{loss}}/{{dataset}}.json",
        particles=f"{RESULTS}/ood/{{loss}}/{{dataset}}.npz",
    log:
        f"logs/{config['dataset']}/ood/{{loss}}_{{dataset}}.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=120,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/ood.py"


rule ood_hand_picked:
    input:
        summaries=[],
        datapoints=prepared(ood_ids()) if 2 in IDENT["levels"] else [],
        code=library(
            "identification",
            "simulation",
            "losses",
            "parameters",
            "datapoint",
            "reporting/frames",
        ),
    output:
        records=f"{RESULTS}/ood/hand-picked.json",
        particles=f"{RESULTS}/ood/hand-picked.npz",
    log:
        f"logs/{config['dataset']}/ood/hand-picked.log",
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=120,
        gpu=1 if config.get("taichi_arch") == "cuda" else 0,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/ood.py"
