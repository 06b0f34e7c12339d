"""Identification runs as the analyses read them: each run's ``summary.json`` and ``log.csv``
(see :mod:`dpsi.identification`) together with the labels that say which run it is (level, loss,
dataset, seed and, for the analyses, material and start), given by the workflow rather than parsed
from paths (an analysis may reuse a run of the main sweep, whose folder has no such labels)."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import pandas as pd


def load_runs(summaries: Sequence[str | os.PathLike], logs: Sequence[str | os.PathLike],
              labels: Sequence[Mapping]) -> tuple[list[dict], pd.DataFrame]:
    """The run summaries, each updated with its labels, and all log rows in one table with the labels
    as extra columns; ``summaries``, ``logs`` and ``labels`` are aligned, one entry per run."""
    if not len(summaries) == len(logs) == len(labels):
        raise ValueError(f"{len(summaries)} summaries, {len(logs)} logs and {len(labels)} labels: "
                         "give one of each per run")
    if not labels:
        raise ValueError("no runs to load")
    records = [{**json.loads(Path(s).read_text()), **label} for s, label in zip(summaries, labels)]
    rows = pd.concat([pd.read_csv(log).assign(**label) for log, label in zip(logs, labels)], ignore_index=True)
    return records, rows


__all__ = ["load_runs"]
