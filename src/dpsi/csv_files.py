"""Reading the CSV files a user writes by hand (the datapoints table, planner trajectories): spaces around
column names and values are dropped, as a reader of the file would expect ("id, motion" names the
column "motion"), and an unreadable file gives an error naming it."""

from __future__ import annotations

import os

import pandas as pd


def read_csv(path: str | os.PathLike, **options) -> pd.DataFrame:
    """The CSV file at ``path`` (``options`` go to :func:`pandas.read_csv`) with the spaces around column
    names and text values stripped; ``ValueError`` naming the file if it is not a readable CSV file."""
    try:
        df = pd.read_csv(path, skipinitialspace=True, **options)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not a readable CSV file ({e})") from None
    df.columns = [str(c).strip() for c in df.columns]
    text = [c for c in df.columns if df[c].dtype == object]
    df[text] = df[text].apply(lambda column: column.str.strip())
    return df


__all__ = ["read_csv"]
