"""Configuration, the datapoints table and helpers shared by every rule file."""

import re
from pathlib import Path

import pandas as pd
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate

from dpsi import datasets as dpsi_datasets
from dpsi.datapoints_table import TableError, check_table, read_table
from dpsi import twin as dpsi_twin

validate(config, "../schemas/config.schema.yaml")

RAW = f"raw/{config['dataset']}"
RESULTS = f"results/{config['dataset']}"
LIBRARY = Path(workflow.main_snakefile).parent / "src" / "dpsi"


def library(*modules):
    """Source files of the dpsi modules a rule uses (names relative to src/dpsi, without .py; a package
    stands for all its files). Declared as inputs so that a change of the library code makes the
    rule's outputs out of date, as a change of its script does."""
    files = []
    for module in modules:
        path = LIBRARY / module
        files += (
            sorted(path.glob("*.py")) if path.is_dir() else [path.with_suffix(".py")]
        )
    return [str(f) for f in files]


def datapoints_table():
    """The datapoints table: planned by the twin config, or read from the raw dataset; checked at parse
    time (ids become file names, so an unsafe id must never reach a rule)."""
    if "twin" in config:
        plan = dpsi_twin.plan_from_config(config["twin"]["groups"])
        table = pd.DataFrame(dpsi_twin.plan_rows(plan))
        check_table(table.astype(str), "the twin's plan")
        return table
    path = Path(RAW) / "datapoints.csv"
    if not path.is_file():
        raise WorkflowError(
            f"{path} not found: put a raw dataset there (docs/raw-format.md) or give a `twin` "
            "section in the config"
        )
    try:
        return read_table(path)
    except TableError as err:
        raise WorkflowError(f"{err} (docs/raw-format.md)")


TABLE = datapoints_table()
IDS = list(TABLE["id"])
IDENT = config["identification"]


def training_ids(level, dataset):
    return dpsi_datasets.select(TABLE, int(level), dataset)


def validation_ids(level):
    return dpsi_datasets.validation(TABLE, int(level))


def ood_ids():
    return dpsi_datasets.ood(TABLE)


def prepared(ids):
    return [f"{RESULTS}/prepared/{i}.npz" for i in ids]


def runs(level=None):
    """Summary files of every identification run (of one level if given)."""
    return expand(
        f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}/summary.json",
        level=[level] if level else IDENT["levels"],
        loss=IDENT["losses"],
        dataset=IDENT["datasets"],
        seed=IDENT["seeds"],
    )


def simulator_params():
    return dict(
        sorted(
            {
                **config.get("simulator", {}),
                "arch": config.get("taichi_arch", "cpu"),
            }.items()
        )
    )


def for_each_run():
    """Fail at start-up, naming the datapoints, if a configured dataset cannot be formed."""
    for level in IDENT["levels"]:
        validation_ids(level)
        for dataset in IDENT["datasets"]:
            training_ids(level, dataset)
    if 2 in IDENT["levels"]:
        ood_ids()


try:
    for_each_run()
except ValueError as err:
    raise WorkflowError(
        f"the configuration asks for a dataset the datapoints cannot form: {err}"
    )


TABLES = ["motions", "parameters", "best_params", "ood_heightmap", "recovery_error"]
OOD_SOURCES = [f"{RESULTS}/ood/hand-picked.json"] + expand(
    f"{RESULTS}/ood/{{loss}}/{{dataset}}.json",
    loss=IDENT["losses"],
    dataset=IDENT["datasets"],
)


def twin_settings():
    twin = config["twin"]
    return {
        "seed": twin["seed"],
        "density": twin["density"],
        "dx": twin["dx"],
        "max_particles": twin.get("max_particles", 22000),
        "groups": [dict(sorted(group.items())) for group in twin["groups"]],
    }


def raw_datapoint(wildcards):
    return [f"{RAW}/{wildcards.id}", f"{RAW}/datapoints.csv"]


def truth_file():
    return [f"{RAW}/truth.json"] if "twin" in config else []


wildcard_constraints:
    id="|".join(map(re.escape, IDS)),
    state="before|after",
    level="1|2",
    seed=r"\d+",
    loss="[a-z_]+",
    dataset="[0-9a-z-]+",


ANALYSES = config.get("analyses", {})
ANALYSIS_TABLES = []
ANALYSIS_FIGURES = []
"""Outputs of the analyses in the config; each analysis rule file adds its own, reporting.smk collects them."""


def parameter_source_inputs(source):
    """Files a parameter source (see dpsi.parameter_sources) is resolved from: the twin's truth for
    `truth`, the level-2 run summaries of the main sweep for `identified`."""
    if source == "truth":
        if "twin" not in config:
            raise WorkflowError(
                "parameters `truth` need a synthetic twin: add a `twin` section to the config or choose "
                "`hand-picked`, `identified` or explicit values"
            )
        return truth_file()
    if source == "identified":
        if 2 not in IDENT["levels"]:
            raise WorkflowError(
                "parameters `identified` need level 2 in identification.levels"
            )
        return runs(level=2)
    return []
