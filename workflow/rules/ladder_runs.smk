"""Configuration and helpers of the identifiability ladder (identifiability.smk makes its rules): the ladder's
folders, its runs with their labels, and the tables that `identifiability` and `tables` build.
"""

import itertools

if "identifiability" in ANALYSES:
    LADDER = ANALYSES["identifiability"]
    RUNGS = ["R0", "R1", "R2", "R1m", "R1r"]
    """The ladder's rungs (dpsi.identifiability.RUNGS)."""
    LADDER_ROOT = f"{RESULTS}/identifiability"
    LADDER_RUN = f"{LADDER_ROOT}/{{rung}}/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}"
    LADDER_REFERENCE = f"{LADDER_ROOT}/{{rung}}/L{{level}}/{{dataset}}/reference.json"
    LADDER_SAME_TARGET = (
        f"{LADDER_ROOT}/R0/L{{level}}/pcd_{{metric}}/{{dataset}}/seed{{seed}}"
    )

    def same_target_run(w):
        """The R0 run of the PRT loss that a PCD loss's R0 run (wildcards `w`) is."""
        return LADDER_RUN.format(
            rung="R0",
            level=w.level,
            loss=f"prt_{w.metric}",
            dataset=w.dataset,
            seed=w.seed,
        )

    def ladder_iterations(rung):
        """Iterations of the ladder's runs on `rung`: one number for all rungs, or one per rung."""
        iterations = LADDER["iterations"]
        if isinstance(iterations, int):
            return iterations
        if rung not in iterations:
            raise WorkflowError(
                f"analyses.identifiability.iterations gives no number for rung {rung}: "
                f"add {rung} to it, or give one number for every rung"
            )
        return iterations[rung]

    def ladder_prepared(rung, ids):
        """Prepared datapoints of a rung: R2 is the main pipeline's (as reconstructed, not registered)."""
        if rung == "R2":
            return [f"{RESULTS}/prepared/{i}.npz" for i in ids]
        return [f"{LADDER_ROOT}/{rung}/prepared/{i}.npz" for i in ids]

    OOD_DATASET = "ood"
    """The ladder's name for the twin's out-of-distribution clay datapoints (the long motions) as a dataset."""

    def ladder_training_ids(level, dataset):
        """Training datapoints of a ladder dataset: a named dataset's, or the OOD datapoints."""
        if dataset == OOD_DATASET:
            return ood_ids()
        return training_ids(level, dataset)

    def ladder_validation_ids(level, dataset):
        """Validation datapoints of a ladder dataset. The OOD datapoints are the only ones of their
        motions, so a run on them is validated on them (its estimate: where it fits them best).
        """
        if dataset == OOD_DATASET:
            return ood_ids()
        return validation_ids(level, dataset)

    def ladder_runs(rungs, losses, datasets):
        """Folder → labels of every ladder run on `rungs` with `losses` and `datasets`."""
        runs = {}
        for rung, level, loss, dataset, seed in itertools.product(
            rungs,
            LADDER["levels"],
            losses,
            datasets,
            LADDER["seeds"],
        ):
            try:
                ladder_training_ids(level, dataset)
                ladder_validation_ids(level, dataset)
            except ValueError as err:
                raise WorkflowError(f"analysis identifiability: {err}")
            labels = dict(rung=rung, level=level, loss=loss, dataset=dataset, seed=seed)
            runs[LADDER_RUN.format(**labels)] = labels
        return runs

    def ladder_references(runs):
        return sorted({LADDER_REFERENCE.format(**labels) for labels in runs.values()})

    OOD_RUNS = LADDER.get("ood_runs", {"rungs": [], "losses": []})

    def run_iterations(rung, dataset):
        """Iterations of a ladder run: `ood_runs.iterations` on dataset ood if given, else the rung's."""
        if dataset == OOD_DATASET and "iterations" in OOD_RUNS:
            return OOD_RUNS["iterations"]
        return ladder_iterations(rung)

    def run_selection(dataset):
        """How a ladder run's best iteration is chosen: `ood_runs.select` on dataset ood, else by validation."""
        if dataset == OOD_DATASET:
            return OOD_RUNS.get("select", "validation")
        return "validation"

    # fail at start-up if a per-rung mapping misses a rung
    for rung in LADDER["rungs"]:
        ladder_iterations(rung)
    for rung in OOD_RUNS["rungs"]:
        run_iterations(rung, OOD_DATASET)
    LADDER_TABLES = {
        "identifiability": {
            **ladder_runs(LADDER["rungs"], LADDER["losses"], LADDER["datasets"]),
            **ladder_runs(OOD_RUNS["rungs"], OOD_RUNS["losses"], [OOD_DATASET]),
        }
    }
    """Name of each ladder table → its runs (folder → labels)."""
    if "in_tables" in LADDER:
        in_tables = {
            "rungs": LADDER["rungs"],
            "losses": LADDER["losses"],
            **LADDER["in_tables"],
        }
        in_table_runs = ladder_runs(
            in_tables["rungs"], in_tables["losses"], LADDER["datasets"]
        )
        if in_table_runs != LADDER_TABLES["identifiability"]:
            LADDER_TABLES["identifiability_" + "-".join(in_tables["rungs"])] = (
                in_table_runs
            )

    LADDER_UNCERTAINTY = LADDER.get("uncertainty", True)
    """Whether the ladder's runs measure what their data determine (dpsi.uncertainty)."""

    def ladder_tables(name):
        """A ladder's tables: its runs, and with uncertainty their intervals and the intervals' coverage of
        the truth."""
        files = table_files(name, "../report/identifiability.rst")
        if LADDER_UNCERTAINTY:
            files += table_files(
                f"{name}_uncertainty", "../report/identifiability_uncertainty.rst"
            )
            files += table_files(f"{name}_coverage", "../report/coverage.rst")
        return files

    def ladder_figures(name):
        """A ladder's figures: the recovery errors, and with uncertainty the intervals."""
        files = figure_files(name, "../report/identifiability_figure.rst")
        if LADDER_UNCERTAINTY:
            files += figure_files(
                f"{name}_uncertainty", "../report/uncertainty_figure.rst"
            )
        return files

    def ladder_outputs(name):
        return ladder_tables(name) + ladder_figures(name)

    TABLES_LADDER = list(LADDER_TABLES)[-1]
    ANALYSIS_TABLES += ladder_tables(TABLES_LADDER)
    ANALYSIS_FIGURES += ladder_figures(TABLES_LADDER)

    def bias_datapoints():
        """The level-1 training datapoints of the ladder's datasets (the sources of bias are per datapoint)."""
        ids = [
            i
            for d in LADDER["datasets"]
            for i in training_ids(min(LADDER["levels"]), d)
        ]
        return list(dict.fromkeys(ids))

    LADDER_LANDSCAPE = f"{LADDER_ROOT}/{{rung}}/L1/{{dataset}}/landscape.npz"
    LANDSCAPE_LABELS = [
        (rung, dataset) for rung in LADDER["rungs"] for dataset in LADDER["datasets"]
    ] + [(rung, OOD_DATASET) for rung in LADDER.get("ood_landscapes", [])]
