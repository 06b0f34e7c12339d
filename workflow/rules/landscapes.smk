"""Loss landscapes (SPEC §7.1): the configured losses over (E, ν) and (σ_y, ρ) on level-1 training datasets
and (μ_t, μ_m) on level-2 ones, the other parameters fixed; one job per (pair, dataset), one figure per pair.
"""

from dpsi import landscapes as dpsi_landscapes

if "landscapes" in ANALYSES:
    LANDSCAPES = ANALYSES["landscapes"]
    LANDSCAPE_PAIRS = {
        pair.name: pair
        for pair in (
            map(dpsi_landscapes.pair_by_name, LANDSCAPES["pairs"])
            if "pairs" in LANDSCAPES
            else dpsi_landscapes.PAIRS
        )
        if pair.level in IDENT["levels"]
    }

    try:
        LANDSCAPE_DATAPOINTS = {
            (name, dataset): training_ids(pair.level, dataset)
            for name, pair in LANDSCAPE_PAIRS.items()
            for dataset in datasets_at(pair.level, LANDSCAPES["datasets"])
        }
    except ValueError as err:
        raise WorkflowError(
            f"analyses.landscapes asks for a dataset the datapoints cannot form: {err}"
        )

    rule landscape:
        input:
            datapoints=lambda w: prepared(LANDSCAPE_DATAPOINTS[w.pair, w.dataset]),
            fixed=parameter_source_inputs(LANDSCAPES["fixed"]),
            code=code("landscape"),
        output:
            f"{RESULTS}/landscapes/{{pair}}/{{dataset}}.npz",
        log:
            log_file("landscapes/{pair}_{dataset}"),
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
            gres=GPU_GRES,
        params:
            resolution=LANDSCAPES["resolution"],
            losses=LANDSCAPES["losses"],
            fixed=LANDSCAPES["fixed"],
            simulator=simulator_params(),
        script:
            "../scripts/landscape.py"

    rule landscape_figure:
        input:
            landscapes=lambda w: expand(
                f"{RESULTS}/landscapes/{w.pair}/{{dataset}}.npz",
                dataset=datasets_at(
                    LANDSCAPE_PAIRS[w.pair].level, LANDSCAPES["datasets"]
                ),
            ),
            code=code("landscape_figure"),
        output:
            figure_files("landscapes_{pair}", "../report/landscapes.rst"),
        log:
            log_file("landscapes/{pair}_figure"),
        wildcard_constraints:
            pair="|".join(LANDSCAPE_PAIRS),
        conda:
            "../envs/dpsi.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=5,
        params:
            datasets=lambda w: datasets_at(
                LANDSCAPE_PAIRS[w.pair].level, LANDSCAPES["datasets"]
            ),
        script:
            "../scripts/landscape_figure.py"

    LANDSCAPE_FIGURES = expand(
        f"{FIGURES_DIR}/landscapes_{{pair}}.{{suffix}}",
        pair=LANDSCAPE_PAIRS,
        suffix=("png", "pdf"),
    )
    ANALYSIS_FIGURES += LANDSCAPE_FIGURES

    rule landscapes:
        input:
            LANDSCAPE_FIGURES,
        localrule: True
