"""Declaring the identification runs of the analyses that are variations of them (materials, minima,
heightmap_losses): `analysis_runs` names their folders, which `identify_analysis` (identification.smk)
makes."""

import itertools

ANALYSIS_RUN = f"{RESULTS}/{{analysis}}/{{material}}/{{start}}/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}"


def in_main_sweep(material, start, level, loss, dataset, seed, iterations):
    """Whether the main sweep makes this very run (then an analysis reuses it)."""
    return (
        material == "clay"
        and start == IDENT.get("initial", "random")
        and iterations == IDENT["iterations"]
        and level in IDENT["levels"]
        and loss in IDENT["losses"]
        and dataset in IDENT["datasets"]
        and seed in IDENT["seeds"]
    )


def analysis_runs(
    analysis,
    level,
    losses,
    datasets,
    seeds,
    materials=("clay",),
    starts=("random",),
):
    """Folders of every run of `analysis` (each run's summary carries its labels): all
    combinations of the given losses, datasets, seeds, materials and starts (`random` or `hand-picked`
    initial values) at `level`, with the analysis's iterations. A run that the main sweep makes anyway
    is taken from runs/. Fails at start-up, naming the datapoints, if a dataset cannot be formed.
    """
    iterations = ANALYSES[analysis]["iterations"]
    runs = []
    for material, start, loss, dataset, seed in itertools.product(
        materials, starts, losses, datasets, seeds
    ):
        try:
            dpsi_datasets.select(TABLE, level, dataset, material)
            dpsi_datasets.validation(TABLE, level, material)
        except ValueError as err:
            raise WorkflowError(f"analysis {analysis}: {err}")
        run = dict(level=level, loss=loss, dataset=dataset, seed=seed)
        if in_main_sweep(material, start, iterations=iterations, **run):
            folder = MAIN_RUN.format(**run)
        else:
            folder = ANALYSIS_RUN.format(
                analysis=analysis, material=material, start=start, **run
            )
        runs.append(folder)
    return runs


def run_files(runs, name):
    """`name` (summary.json or log.csv) in each folder of `runs` (from `analysis_runs`)."""
    return [f"{folder}/{name}" for folder in runs]
