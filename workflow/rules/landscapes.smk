"""Loss landscapes (SPEC §7.1): the configured losses over (E, ν) and (σ_y, ρ) on level-1 training datasets
and (μ_t, μ_m) on level-2 ones, the other parameters fixed; one job per (pair, dataset), one figure per pair.
"""

from dpsi import landscapes as dpsi_landscapes

if "landscapes" in ANALYSES:
    LANDSCAPES = ANALYSES["landscapes"]
    LANDSCAPE_PAIRS = {
        pair.name: pair
        for pair in dpsi_landscapes.PAIRS
        if pair.level in IDENT["levels"]
    }

    try:
        LANDSCAPE_DATAPOINTS = {
            (name, dataset): training_ids(pair.level, dataset)
            for name, pair in LANDSCAPE_PAIRS.items()
            for dataset in LANDSCAPES["datasets"]
        }
    except ValueError as err:
        raise WorkflowError(
            f"analyses.landscapes asks for a dataset the datapoints cannot form: {err}"
        )

    rule landscape:
        input:
            datapoints=lambda w: prepared(LANDSCAPE_DATAPOINTS[w.pair, w.dataset]),
            fixed=parameter_source_inputs(LANDSCAPES["fixed"]),
            code=library(
                "landscapes",
                "identification",
                "simulation",
                "losses",
                "parameters",
                "parameter_sources",
                "datapoint",
            ),
        output:
            f"{RESULTS}/landscapes/{{pair}}/{{dataset}}.npz",
        log:
            f"logs/{config['dataset']}/landscapes/{{pair}}_{{dataset}}.log",
        wildcard_constraints:
            pair="|".join(LANDSCAPE_PAIRS),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            # minutes: up to 30 s per simulation on a CPU at the stiff corners
            runtime=lambda w: 10
            + len(LANDSCAPE_DATAPOINTS[w.pair, w.dataset])
            * LANDSCAPES["resolution"] ** 2
            // 2,
            gpu=1 if config.get("taichi_arch") == "cuda" else 0,
        params:
            resolution=LANDSCAPES["resolution"],
            losses=LANDSCAPES["losses"],
            fixed=LANDSCAPES["fixed"],
            simulator=simulator_params(),
        script:
            "../scripts/landscape.py"

    rule landscape_figure:
        input:
            landscapes=expand(
                f"{RESULTS}/landscapes/{{{{pair}}}}/{{dataset}}.npz",
                dataset=LANDSCAPES["datasets"],
            ),
            code=library("landscapes", "reporting"),
        output:
            png=report(
                "results/figures/landscapes_{pair}.png",
                caption="../report/landscapes.rst",
                category="Figures",
            ),
            pdf=report(
                "results/figures/landscapes_{pair}.pdf",
                caption="../report/landscapes.rst",
                category="Figures",
            ),
        log:
            "logs/landscapes/{pair}_figure.log",
        wildcard_constraints:
            pair="|".join(LANDSCAPE_PAIRS),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        script:
            "../scripts/landscape_figure.py"

    LANDSCAPE_FIGURES = expand(
        "results/figures/landscapes_{pair}.{suffix}",
        pair=LANDSCAPE_PAIRS,
        suffix=("png", "pdf"),
    )
    ANALYSIS_FIGURES += LANDSCAPE_FIGURES

    rule landscapes:
        input:
            LANDSCAPE_FIGURES,
        localrule: True
