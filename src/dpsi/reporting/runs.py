"""Identification runs as the reports read them: each run's ``summary.json`` and ``log.csv`` (see
:mod:`dpsi.identification`), labelled by the labels its summary carries (level, loss, dataset, seed,
start, material), never by its path (an analysis may reuse a run of the main sweep)."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

LABELS = ("level", "loss", "dataset", "seed", "start", "material")
"""What a run's summary says it is."""


def read_summary(path: str | os.PathLike) -> dict:
    """A run summary with its labels as top-level keys; ``ValueError`` naming the file if it has none."""
    summary = json.loads(Path(path).read_text())
    labels = summary.get("labels") or {}
    missing = [k for k in LABELS if k not in labels]
    if missing:
        raise ValueError(f"{path}: run summary lacks the label(s) {missing}; it was written by an older "
                         "version: delete it to rerun the identification")
    return {**summary, **labels}


def load_runs(summaries: Sequence[str | os.PathLike],
              logs: Sequence[str | os.PathLike]) -> tuple[list[dict], pd.DataFrame]:
    """The run summaries (labels as keys) and all log rows in one table with each run's labels (those of
    :data:`LABELS` and any other its summary carries, e.g. the ladder's rung) as extra columns;
    ``summaries`` and ``logs`` are aligned, one entry per run."""
    if len(summaries) != len(logs):
        raise ValueError(f"{len(summaries)} summaries and {len(logs)} logs: give one of each per run")
    if not summaries:
        raise ValueError("no runs to load")
    records = [read_summary(s) for s in summaries]
    rows = pd.concat([pd.read_csv(log).assign(**r["labels"]) for log, r in zip(logs, records)], ignore_index=True)
    return records, rows


__all__ = ["LABELS", "read_summary", "load_runs"]
