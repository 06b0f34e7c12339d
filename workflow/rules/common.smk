"""Configuration, the datapoints table and helpers shared by every rule file. Only the light layer of the
library is imported here (no Taichi, Open3D or PyMeshLab), so that parsing the workflow stays fast.
"""

import ast
import functools
import itertools
import math
import os
import re
from pathlib import Path

import pandas as pd
from snakemake.exceptions import WorkflowError
from snakemake.logging import logger
from snakemake.utils import validate

from dpsi import datasets as dpsi_datasets
from dpsi import release_plan, twin_plan
from dpsi.dataset_yaml import DatasetYamlError, read_dataset_yaml
from dpsi.datapoints_table import TableError, check_table, read_table
from dpsi.motions import MOTIONS
from dpsi.parameters import check_known

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
RELEASE = "release" in config and config["release"]["name"] == config["dataset"]
"""Whether the dataset is imported from the published real data (dpsi.release)."""
if TWIN and RELEASE:
    raise WorkflowError(
        f"config: `twin` and `release` are both named {config['dataset']!r}; give them different names"
    )
RESULTS = f"{OUT}/{config['dataset']}"
"""Everything made from this dataset: prepared data, runs, tables, figures and logs."""
RAW = f"{RESULTS}/raw" if TWIN or RELEASE else f"raw/{config['dataset']}"
"""The raw dataset: the twin and the import write theirs under the results; a user's under raw/ is only read."""
TABLES_DIR = f"{RESULTS}/tables"
FIGURES_DIR = f"{RESULTS}/figures"
LOGS = f"{RESULTS}/logs"
SCRIPTS = Path(workflow.main_snakefile).parent / "workflow" / "scripts"
GPU_GRES = (
    f"{os.environ.get('DPSI_GPU_GRES', 'gpu')}:1"
    if config.get("taichi_arch") == "cuda"
    else None
)
"""The GPU a simulating job asks for, as a generic resource (SLURM's --gres): one `gpu`, or one of the
name in the environment variable DPSI_GPU_GRES (such as gpu:a100); none (None) on the CPU."""


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


@functools.cache
def released_pairs():
    """The datapoints of the published real data that the config's `release` section imports, each with its
    pair of mesh files; refused at start-up naming the source if there are none."""
    try:
        return release_plan.plan_rows(
            config["release"]["source"],
            release_plan.ImportTables.from_config(config["release"]),
        )
    except release_plan.ReleaseError as err:
        raise WorkflowError(f"config `release`: {err}")


def raw_layout():
    """The raw dataset's dataset.yaml, checked at parse time (a file it names must exist before a rule
    depends on it). The twin writes its own: until then, the defaults."""
    try:
        return read_dataset_yaml(RAW)
    except DatasetYamlError as err:
        raise WorkflowError(f"{err} (docs/raw-format.md)")


LAYOUT = raw_layout()


def datapoints_table():
    """The datapoints table: planned by the twin config, or read from the raw dataset; checked at parse
    time (ids become file names, so an unsafe id must never reach a rule; each motion with its effector).
    """
    if TWIN:
        plan = twin_plan.plan_from_config(config["twin"]["groups"])
        table = pd.DataFrame(twin_plan.plan_rows(plan))
        check_table(table.astype(str), "the twin's plan")
        return table
    if RELEASE:
        return pd.DataFrame([row for row, _ in released_pairs()])
    path = Path(RAW) / "datapoints.csv"
    if not path.is_file():
        raise WorkflowError(
            f"{path} not found: put a raw dataset there (docs/raw-format.md), or set `dataset` to "
            "the name of the config's `twin` to generate a synthetic one"
        )
    try:
        return read_table(path, LAYOUT.kinds())
    except TableError as err:
        raise WorkflowError(f"{err} (docs/raw-format.md)")


TABLE = datapoints_table()
IDS = list(TABLE["id"])
IDENT = config["identification"]


def training_ids(level, dataset):
    return dpsi_datasets.select(TABLE, int(level), dataset)


def validation_ids(level, dataset):
    """The validation datapoints of a run on ``dataset``: the level's validation ones, or those of its
    train datapoints the dataset leaves out (see dpsi.datasets.validation)."""
    return dpsi_datasets.validation(
        TABLE, int(level), training=training_ids(level, dataset)
    )


def datasets_at(level, names):
    """The datasets ``names`` at ``level``, `pairs` expanded to one dataset per train datapoint."""
    return dpsi_datasets.expand_names(TABLE, int(level), names)


def run_datasets(level):
    """The main sweep's datasets at ``level``."""
    return datasets_at(level, IDENT["datasets"])


def unseen_ids(level, dataset):
    """The clay datapoints (either level) a run on ``dataset`` did not train on."""
    return dpsi_datasets.unseen(TABLE, training_ids(level, dataset))


def ood_ids():
    return dpsi_datasets.ood(TABLE)


OFFSETS = IDENT.get("motion_offsets", False)
"""Whether each datapoint's motion offset is registered from its dent before it is used (dpsi.motion_offsets)."""


def prepared(ids):
    """The datapoints ``ids`` as the sweep uses them: prepared, and registered if `motion_offsets` is on."""
    return [f"{RESULTS}/{'registered' if OFFSETS else 'prepared'}/{i}.npz" for i in ids]


def level_of(datapoint):
    """The level of a datapoint in the table."""
    return int(TABLE.set_index("id").loc[datapoint, "level"])


MAIN_RUN = f"{RESULTS}/runs/L{{level}}/{{loss}}/{{dataset}}/seed{{seed}}"
"""Folder of a run of the main sweep."""


def runs(level=None, name="summary.json"):
    """``name`` (summary.json or log.csv) of every identification run (of one level if given)."""
    return [
        path
        for each in ([level] if level else IDENT["levels"])
        for path in expand(
            f"{MAIN_RUN}/{name}",
            level=each,
            loss=IDENT["losses"],
            dataset=run_datasets(each),
            seed=IDENT["seeds"],
        )
    ]


def baselines():
    """The baseline record of every (level, datapoint) that a run of the sweep validates on or did not see."""
    return sorted(
        {
            f"{RESULTS}/baselines/L{level}/{i}.json"
            for level in IDENT["levels"]
            for dataset in run_datasets(level)
            for i in validation_ids(level, dataset) + unseen_ids(level, dataset)
        }
    )


def run_minutes(ids, iterations):
    """Time limit (min) of an identification run on the datapoints ``ids`` (training and validation): ten for
    start-up and a minute per 100 simulated steps of each datapoint at every iteration, about three times
    a poking-shifting pass at 5 mm on one core (docs/benchmarks.md)."""
    steps = sum(MOTIONS[m].sim_steps for m in TABLE.set_index("id").motion[list(ids)])
    return 10 + math.ceil(iterations * steps / 100)


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
        for dataset in run_datasets(level):
            validation_ids(level, dataset)
            if not re.fullmatch("[0-9a-z-]+", dataset):
                raise ValueError(
                    f"dataset {dataset!r}: ids of datasets may hold only lower-case letters, digits and '-'"
                )


try:
    for_each_run()
except ValueError as err:
    raise WorkflowError(
        f"the configuration asks for a dataset the datapoints cannot form: {err}"
    )


def check_known_parameters():
    """Fail at start-up, naming the config key, if parameters held known are not identified at a level
    of the runs they are given for."""
    ladder = ANALYSES.get("identifiability", {})
    for key, known, levels in [
        ("identification.known", IDENT.get("known", {}), IDENT["levels"]),
        (
            "analyses.identifiability.known",
            ladder.get("known", {}),
            ladder.get("levels", []),
        ),
    ]:
        for level in levels:
            try:
                check_known(known, level)
            except ValueError as err:
                raise WorkflowError(f"config key {key}: {err}")


OOD = 2 in IDENT["levels"] and (TABLE.role == "ood").any()
"""Whether the out-of-distribution evaluation runs (it uses the level-2 parameters)."""
TABLES = [
    "motions",
    "parameters",
    "best_params",
    "generalisation",
    "ood_heightmap",
    "recovery_error",
]
UNCERTAINTY = IDENT.get("uncertainty", False)
"""Whether the main sweep's runs measure what their data determine (dpsi.uncertainty): uncertainty.csv and figure."""
if UNCERTAINTY:
    TABLES.append("uncertainty")
OOD_SOURCES = [f"{RESULTS}/ood/hand-picked.json"] + expand(
    f"{RESULTS}/ood/{{loss}}/{{dataset}}.json",
    loss=IDENT["losses"],
    dataset=run_datasets(2) if OOD else [],
)


def twin_settings():
    twin = config["twin"]
    return {
        "seed": twin["seed"],
        "density": twin["density"],
        "dx": twin["dx"],
        "max_particles": twin.get("max_particles", 22000),
        "groups": [dict(sorted(group.items())) for group in twin["groups"]],
        "motion_error": dict(sorted(twin.get("motion_error", {}).items())),
    }


def raw_config_files():
    """The raw dataset's table and layout (dataset.yaml, with the mesh files of its own effectors)."""
    layout = Path(f"{RAW}/dataset.yaml")
    files = [f"{RAW}/datapoints.csv"]
    if TWIN or layout.is_file():
        files.append(str(layout))
    return files + [
        str(spec.obj) for spec in LAYOUT.effectors.values() if spec.obj is not None
    ]


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
check_known_parameters()


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
