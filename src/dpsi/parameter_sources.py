"""Where an analysis takes its fixed parameters θ from: a name in the config, resolved to values.

- ``"hand-picked"``: :data:`~dpsi.parameters.HAND_PICKED`;
- ``"truth"``: the synthetic twin's ground truth of a material (``truth.json``, :func:`dpsi.twin_plan.load_truth`);
- ``"identified"``: the best iteration (lowest validation height-map distance) among run summaries;
- a mapping of some parameter names to values: those values, the others hand-picked.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from dpsi.parameters import HAND_PICKED, Parameters
from dpsi.twin_plan import load_truth

SOURCES = ("hand-picked", "truth", "identified")


def best_run(summaries: Sequence[Mapping]) -> dict:
    """The ``best`` entry (iteration, parameters, validation) with the lowest validation height-map
    distance among run summaries (``summary.json`` contents); ``ValueError`` if no run has a best."""
    bests = [s["best"] for s in summaries if s.get("best")]
    if not bests:
        raise ValueError(f"none of the {len(summaries)} run summaries has a best iteration "
                         "(every iteration was skipped); rerun them or choose other parameters")
    return min(bests, key=lambda b: b["validation"]["heightmap_mm"])


def resolve(source: str | Mapping[str, float], truth_root: str | os.PathLike | None = None,
            summaries: Sequence[str | os.PathLike] = (), material: str = "clay") -> Parameters:
    """The parameters named by ``source`` (see the module doc). ``truth_root`` is the twin's raw folder
    (needed for ``"truth"``), ``summaries`` the run summary files (needed for ``"identified"``)."""
    if isinstance(source, Mapping):
        return HAND_PICKED.replace(**source)
    if source == "hand-picked":
        return HAND_PICKED
    if source == "truth":
        if truth_root is None:
            raise ValueError("parameters 'truth' need a synthetic twin (a `twin` section in the config); "
                             "real captures have no ground truth")
        materials = load_truth(truth_root)["materials"]
        if material not in materials:
            raise ValueError(f"the twin's truth has no material {material!r}; it has {sorted(materials)}")
        return materials[material]
    if source == "identified":
        if not summaries:
            raise ValueError("parameters 'identified' need identification runs; none were given")
        best = best_run([json.loads(Path(p).read_text()) for p in summaries])
        return Parameters.checked(**best["parameters"])
    raise ValueError(f"unknown parameter source {source!r}; use one of {list(SOURCES)} or a mapping of values")


def resolve_from_files(source: str | Mapping[str, float], files: Sequence[str | os.PathLike],
                       material: str = "clay") -> Parameters:
    """:func:`resolve` given the files the source needs, as a workflow lists them: the twin's
    ``truth.json`` for ``"truth"``, the run summaries for ``"identified"``, nothing otherwise."""
    if source == "truth":
        if not files:
            return resolve(source, None)
        return resolve(source, truth_root=Path(files[0]).parent, material=material)
    return resolve(source, summaries=files if source == "identified" else ())


__all__ = ["SOURCES", "best_run", "resolve", "resolve_from_files"]
