"""Out-of-distribution generalisation (SPEC §7.3): the long motions simulated with the best level-2
parameters of each (loss, dataset), and with the hand-picked ones."""


rule ood_identified:
    input:
        summaries=expand(
            f"{MAIN_RUN}/summary.json",
            level=2,
            seed=IDENT["seeds"],
            allow_missing=True,
        ),
        datapoints=prepared(ood_ids()) if OOD else [],
        code=code("ood"),
    output:
        records=f"{RESULTS}/ood/{{loss}}/{{dataset}}.json",
        particles=f"{RESULTS}/ood/{{loss}}/{{dataset}}.npz",
    log:
        log_file("ood/{loss}_{dataset}"),
    conda:
        "../envs/dpsi.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=120,
        gres=GPU_GRES,
    params:
        simulator=simulator_params(),
    script:
        "../scripts/ood.py"


use rule ood_identified as ood_hand_picked with:
    input:
        summaries=[],
        datapoints=prepared(ood_ids()) if OOD else [],
        code=code("ood"),
    output:
        records=f"{RESULTS}/ood/hand-picked.json",
        particles=f"{RESULTS}/ood/hand-picked.npz",
    log:
        log_file("ood/hand-picked"),
