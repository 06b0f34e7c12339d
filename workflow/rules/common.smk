"""Configuration, the datapoints table and helpers shared by every rule file. Only the light layer of the
library is imported here (no Taichi, Open3D or PyMeshLab), so that parsing the workflow stays fast.
"""

import ast
import functools
import itertools
import re
from pathlib import Path

import pandas as pd
import yaml
from snakemake.exceptions import WorkflowError
from snakemake.logging import logger
from snakemake.utils import validate

from dpsi import datasets as dpsi_datasets
from dpsi import twin_plan
from dpsi.datapoints_table import TableError, check_table, read_table

validate(config, "../schemas/config.schema.yaml")

PROJECT = Path(workflow.main_snakefile).parent
SRC = PROJECT / "src"


def inside_project(key):
    """The config's relative path ``key``, refused at start-up unless it stays inside the project (the
    working directory): results and raw data are written and read only there."""
    value = config[key]
    here = Path.cwd().resolve()
    if Path(value).is_absolute() or here not in (here / value).resolve().parents:
        raise WorkflowError(
            f"config key `{key}`: {value!r} leaves the project folder {here}; give a path inside it, "
            "e.g. `results` or `results/paper`"
        )
    return value


OUT = inside_project("results")
"""Output root of this configuration."""
TWIN = "twin" in config and config["twin"]["name"] == config["dataset"]
"""Whether the dataset is the synthetic twin of the config (generated), rather than a user's raw data."""
RESULTS = f"{OUT}/{config['dataset']}"
"""Everything made from this dataset: prepared data, runs, tables, figures and logs."""
RAW = f"{RESULTS}/raw" if TWIN else f"raw/{config['dataset']}"
"""The raw dataset: the twin writes its own under the results, a user's under raw/ is only read."""
TABLES_DIR = f"{RESULTS}/tables"
FIGURES_DIR = f"{RESULTS}/figures"
LOGS = f"{RESULTS}/logs"
SCRIPTS = Path(workflow.main_snakefile).parent / "workflow" / "scripts"
GPU = 1 if config.get("taichi_arch") == "cuda" else 0
"""GPUs a simulating job asks for."""


def _module_file(name):
    """Source file of the dpsi module or package ``name`` (dotted), or None if there is none."""
    base = SRC.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


@functools.cache
def _imported(path, dotted):
    """Dotted names of the dpsi modules the file ``path`` (of module ``dotted``) may import, its packages
    included."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            parts = dotted.split(".")
            keep = len(parts) - node.level + (path.name == "__init__.py")
            package = parts[:keep]
            base = (
                ".".join(package + ([node.module] if node.module else []))
                if node.level
                else node.module
            )
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    parents = {
        ".".join(n.split(".")[:k]) for n in names for k in range(1, n.count(".") + 1)
    }
    return sorted(n for n in names | parents if n == "dpsi" or n.startswith("dpsi."))


@functools.cache
def code(script):
    """Library files that ``workflow/scripts/<script>.py`` imports, directly or through other modules
    (found with ast): declared as inputs, so that a change of library code reruns what depends on it, as
    a change of the script does."""
    files, todo, seen = set(), [("__main__", SCRIPTS / f"{script}.py")], set()
    while todo:
        dotted, path = todo.pop()
        for name in _imported(path, dotted):
            found = _module_file(name)
            if found is not None and name not in seen:
                seen.add(name)
                files.add(found)
                todo.append((name, found))
    return sorted(map(str, files))


def log_file(name):
    """The log of a job: ``<output root>/logs/<name>.log``."""
    return f"{LOGS}/{name}.log"


def table_files(name, caption=None):
    """A table's CSV (in the report with ``caption``, if given), Markdown and LaTeX files; scripts write the
    CSV's path with dpsi.reporting.tables.write_table, which writes the other two beside it.
    """
    path = f"{TABLES_DIR}/{name}"
    csv = f"{path}.csv"
    if caption:
        csv = report(csv, caption=caption, category="Tables")
    return [csv, f"{path}.md", f"{path}.tex"]


def figure_files(name, caption):
    """A figure's PNG (in the report with ``caption``) and PDF."""
    path = f"{FIGURES_DIR}/{name}"
    png = report(f"{path}.png", caption=caption, category="Figures")
    return [png, f"{path}.pdf"]


def datapoints_table():
    """The datapoints table: planned by the twin config, or read from the raw dataset; checked at parse
    time (ids become file names, so an unsafe id must never reach a rule)."""
    if TWIN:
        plan = twin_plan.plan_from_config(config["twin"]["groups"])
        table = pd.DataFrame(twin_plan.plan_rows(plan))
        check_table(table.astype(str), "the twin's plan")
        return table
    path = Path(RAW) / "datapoints.csv"
    if not path.is_file():
        raise WorkflowError(
            f"{path} not found: put a raw dataset there (docs/raw-format.md), or set `dataset` to "
            "the name of the config's `twin` to generate a synthetic one"
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


MAIN_RUN = f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}"
"""Folder of a run of the main sweep."""


def runs(level=None, name="summary.json"):
    """``name`` (summary.json or log.csv) of every identification run (of one level if given)."""
    return expand(
        f"{MAIN_RUN}/{name}",
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


OOD = 2 in IDENT["levels"]
"""Whether the out-of-distribution evaluation runs (it uses the level-2 parameters)."""
TABLES = ["motions", "parameters", "best_params", "ood_heightmap", "recovery_error"]
UNCERTAINTY = IDENT.get("uncertainty", False)
"""Whether the main sweep's runs measure what their data determine (dpsi.uncertainty): uncertainty.csv and figure."""
if UNCERTAINTY:
    TABLES.append("uncertainty")
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


def raw_config_files():
    """The raw dataset's table and layout (dataset.yaml, with the mesh files of its own effectors)."""
    layout = Path(f"{RAW}/dataset.yaml")
    files = [f"{RAW}/datapoints.csv"]
    if TWIN or layout.is_file():
        files.append(str(layout))
    if layout.is_file():
        effectors = (yaml.safe_load(layout.read_text()) or {}).get("effectors") or {}
        files += [
            f"{RAW}/{e['obj']}"
            for e in effectors.values()
            if isinstance(e, dict) and "obj" in e
        ]
    return files


def raw_datapoint(wildcards):
    """Raw inputs of one datapoint: its folder, the dataset's table and layout, and the planner
    trajectory of its motion (when the dataset has one shared by the motion's datapoints).
    """
    motion = TABLE.set_index("id").motion[wildcards.id]
    shared = Path(f"{RAW}/trajectories/{motion}.csv")
    return [f"{RAW}/{wildcards.id}", *raw_config_files()] + (
        [str(shared)] if shared.is_file() else []
    )


def truth_file():
    return [f"{RAW}/truth.json"] if TWIN else []


wildcard_constraints:
    id="|".join(map(re.escape, IDS)),
    state="before|after",
    level="1|2",
    seed=r"\d+",
    loss="[a-z_]+",
    dataset="[0-9a-z-]+",


def needs_truth(analysis, settings):
    """Whether an analysis compares with, or starts from, the synthetic twin's ground truth."""
    return analysis in ("identifiability", "materials") or "truth" in (
        settings.get("fixed"),
        settings.get("parameters"),
    )


ANALYSES = {
    name: settings
    for name, settings in config.get("analyses", {}).items()
    if TWIN or not needs_truth(name, settings)
}
"""The configured analyses that this dataset allows (those needing the truth only on the twin)."""
if set(config.get("analyses", {})) - set(ANALYSES):
    logger.warning(
        f"dataset {config['dataset']!r} is not the synthetic twin, so the analyses that need its ground "
        f"truth are left out: {sorted(set(config.get('analyses', {})) - set(ANALYSES))}"
    )
ANALYSIS_TABLES = []
ANALYSIS_FIGURES = []
"""Outputs of the analyses in the config; each analysis rule file adds its own, reporting.smk collects them."""


def parameter_source_inputs(source):
    """Files a parameter source (see dpsi.parameter_sources) is resolved from: the twin's truth for
    `truth`, the level-2 run summaries of the main sweep for `identified`."""
    if source == "truth":
        return truth_file()
    if source == "identified":
        if 2 not in IDENT["levels"]:
            raise WorkflowError(
                "parameters `identified` need level 2 in identification.levels"
            )
        return runs(level=2)
    return []
