"""Option types of the command-line entry points (``python -m dpsi``, ``python -m dpsi.convergence``,
``python -m dpsi.bench``): each turns an option's text into its value, or raises
:class:`argparse.ArgumentTypeError` saying what the option must be (argparse then names the option and
exits with status 2, without a traceback)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from collections.abc import Callable, Collection


def finite(text: str) -> float:
    """A finite number."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0 or value == math.inf:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def at_least(minimum: int) -> Callable[[str], int]:
    """An integer ≥ ``minimum``."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer ≥ {minimum}, got {text!r}")
        return value
    return parse


def simulator_settings(set_elsewhere: Collection[str] = ()) -> Callable[[str], dict]:
    """A JSON object of :class:`~dpsi.simulation.SimulatorConfig` settings, checked by building one; the
    settings ``set_elsewhere`` (by the command itself) are refused."""
    def parse(text: str) -> dict:
        from dpsi.simulation.config import SimulatorConfig

        try:
            settings = json.loads(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"must be a JSON object, got {text!r} ({err})") from None
        if not isinstance(settings, dict):
            raise argparse.ArgumentTypeError(f"must be a JSON object, got {text!r}")
        known = {f.name for f in dataclasses.fields(SimulatorConfig)} - set(set_elsewhere)
        unknown = sorted(set(settings) - known)
        if unknown:
            raise argparse.ArgumentTypeError(f"unknown or fixed setting(s) {unknown}; it takes {sorted(known)}")
        try:
            SimulatorConfig(**settings)
        except (TypeError, ValueError) as err:
            raise argparse.ArgumentTypeError(str(err)) from None
        return settings
    return parse


__all__ = ["finite", "positive", "at_least", "simulator_settings"]
