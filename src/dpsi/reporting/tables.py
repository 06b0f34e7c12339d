"""The paper's tables (SPEC §7) as pandas DataFrames, written as CSV, Markdown and LaTeX (booktabs).

File names and CSV columns are an interface that other tools read:

- ``motions.csv``: motion, segments, duration_s, real_waypoints, sim_steps
- ``parameters.csv``: parameter, unit, min, max, step_level1, step_level2, hand_picked
- ``best_params.csv``: level, loss, dataset, E, nu, rho, yield_stress, mu_table, mu_effector,
  val_heightmap_mm, hand_picked_mm, no_motion_mm, recommended, at_bound (plus rows with dataset = "average" per loss,
  and loss = "hand-picked"), then the interval <parameter>_low, <parameter>_high of each parameter the run
  measured it for (:mod:`dpsi.uncertainty`)
- ``generalisation.csv``: level, loss, dataset, seed, pair, identified_mm, hand_picked_mm, no_motion_mm, change
- ``uncertainty.csv``: rung, level, loss, dataset, seed, quantity, estimate, low, high, determined, truth (rung
  and truth empty where they do not apply)
- ``ood_heightmap.csv``: motion, config, loss, dataset, heightmap_mm (plus loss = "hand-picked" rows
  and "average" rows)
- ``recovery_error.csv``: level, loss, dataset, seed, parameter (and E/rho, yield_stress/E), truth, estimate, rel_error
- ``materials.csv``: material, parameter, truth, seed<s> (one per seed), estimate, rel_error,
  val_heightmap_mm
- ``minima.csv``: dataset, start, seed, best_iteration, val_heightmap_mm, E, nu, rho, yield_stress
- ``heightmap_losses.csv``: loss, dataset, seed, best_iteration, val_pcd_cd, val_prt_cd, val_pcd_emd,
  val_prt_emd, val_heightmap_mm (plus dataset = "average" rows per loss)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from ..motions import MOTIONS, plan, resample
from ..losses import VALIDATION_METRICS
from ..parameters import HAND_PICKED, IDENTIFIED, LOWER, NAMES, STEP_SIZE, UNITS, UPPER, at_bound, hand_picked, scale_free
from ..files import atomic_output
from ..uncertainty import true_value
from ..generalisation import DECIDING_METRIC

HAND_PICKED_LABEL = "hand-picked"
AVERAGE_LABEL = "average"


def motions_table() -> pd.DataFrame:
    """SPEC §2: each motion's segments, real duration and waypoints, and the simulation steps that
    resampling its planner trajectory gives."""
    rows = []
    for name, motion in MOTIONS.items():
        segments = ", ".join(_segment_label(s) for s in motion.segments)
        steps = resample(plan(motion)).n_steps
        rows.append(dict(motion=name, segments=segments, duration_s=motion.duration,
                         real_waypoints=motion.n_waypoints, sim_steps=steps))
    return pd.DataFrame(rows)


def _segment_label(segment) -> str:
    sign = "+" if segment.amount > 0 else "-"
    if segment.kind == "rotate":
        return f"rotate {sign}{abs(math.degrees(segment.amount)):.0f} deg about z"
    return f"{sign}{segment.axis} {abs(segment.amount):.3f} m"


def parameters_table() -> pd.DataFrame:
    """SPEC §1: ranges, Adam step sizes per level and the hand-picked values."""
    return pd.DataFrame([dict(parameter=n, unit=UNITS[n], min=LOWER[n], max=UPPER[n], step_level1=STEP_SIZE[1][n],
                              step_level2=STEP_SIZE[2][n], hand_picked=getattr(HAND_PICKED, n)) for n in NAMES])


def best_params_table(summaries: list[dict], baselines: Mapping[tuple[int, str], Mapping],
                      recommended: Mapping[int, tuple[str, str, int]] | None = None) -> pd.DataFrame:
    """The paper's main table: for each (level, loss, dataset) the parameters of the iteration with the
    lowest validation height-map distance across seeds, beside the hand-picked values' and no motion's
    distance on the same validation datapoints; per (level, loss) the average over datasets; per level the
    hand-picked parameters with their distance over every validation datapoint of the level.
    ``recommended`` marks one row per level (level → (loss, dataset, seed), :func:`dpsi.generalisation.recommend`).
    Column ``at_bound`` names each identified parameter that ends exactly on a bound of its range
    (``E=upper; nu=lower``): clipping put it there, and the data may want a value outside the range.
    The intervals of the parameters whose run measured them follow (:data:`INTERVAL_COLUMNS`, only those some
    run has).

    ``summaries``: run summaries (identification ``summary.json``) with keys level, loss, dataset;
    ``baselines``: (level, datapoint id) → :func:`dpsi.generalisation.baseline` record."""
    recommended = recommended or {}

    def baseline_mm(level: int, ids, which: str) -> float:
        return float(np.mean([baselines[(level, i)][which][DECIDING_METRIC] for i in ids]))

    rows, validated = [], {}
    for (level, loss, dataset), runs in _group(summaries, ("level", "loss", "dataset")):
        run = _best_run(runs) or runs[0]
        best = run.get("best")
        ids = [entry[0] for entry in run["validation"]]
        validated.setdefault(level, []).extend(i for i in ids if i not in validated.get(level, []))
        values = best["parameters"] if best else {n: math.nan for n in NAMES}
        rows.append(dict(level=level, loss=loss, dataset=dataset, **values,
                         val_heightmap_mm=best["validation"]["heightmap_mm"] if best else math.nan,
                         hand_picked_mm=baseline_mm(level, ids, "hand_picked"),
                         no_motion_mm=baseline_mm(level, ids, "no_motion"),
                         recommended=recommended.get(level, (None,) * 3)[:2] == (loss, dataset)
                         and recommended[level][2] == run["seed"], at_bound=_at_bound_label(run),
                         **_parameter_intervals(run)))
    columns = ["level", "loss", "dataset", *NAMES, "val_heightmap_mm", "hand_picked_mm", "no_motion_mm"]
    table = pd.DataFrame(rows, columns=[*columns, "recommended", "at_bound", *INTERVAL_COLUMNS])
    averages = (table.groupby(["level", "loss"], sort=False)[columns[3:]].mean().reset_index()
                .assign(dataset=AVERAGE_LABEL, recommended=False, at_bound=""))
    baseline = pd.DataFrame([dict(level=level, loss=HAND_PICKED_LABEL, dataset="", **hand_picked(level).as_dict(),
                                  val_heightmap_mm=baseline_mm(level, ids, "hand_picked"),
                                  hand_picked_mm=baseline_mm(level, ids, "hand_picked"),
                                  no_motion_mm=baseline_mm(level, ids, "no_motion"), recommended=False,
                                  at_bound="")
                             for level, ids in sorted(validated.items())])
    measured = [c for c in table.columns if c not in INTERVAL_COLUMNS or table[c].notna().any()]
    return (pd.concat([table, averages, baseline], ignore_index=True)
            .sort_values(["level"], kind="stable")[measured].reset_index(drop=True))


INTERVAL_COLUMNS = tuple(f"{n}_{end}" for n in NAMES for end in ("low", "high"))
"""best_params.csv's interval columns (SI units; empty where the run did not measure one)."""


def _parameter_intervals(summary: dict) -> dict[str, float]:
    """The interval of each parameter in ``summary``'s uncertainty block, as :data:`INTERVAL_COLUMNS`."""
    measured = {q["quantity"]: q for q in (summary.get("uncertainty") or {}).get("quantities", [])}
    return {f"{n}_{end}": measured[n][end] if n in measured else math.nan for n in NAMES for end in ("low", "high")}


UNCERTAINTY_COLUMNS = ("rung", "level", "loss", "dataset", "seed", "quantity", "estimate", "low", "high", "determined",
                       "truth")


def uncertainty_table(summaries: list[dict]) -> pd.DataFrame:
    """What each run's data determine (:mod:`dpsi.uncertainty`): one row per run and quantity of its uncertainty
    block, with the quantity's value at the run's truth where the summary has one. ``rung`` is empty for runs
    that are not on the identifiability ladder, ``truth`` for runs with no known truth."""
    rows = [dict(rung=s.get("rung", ""), level=s["level"], loss=s["loss"], dataset=s["dataset"], seed=s["seed"],
                 quantity=q["quantity"], estimate=q["estimate"], low=q["low"], high=q["high"],
                 determined=q["determined"],
                 truth=true_value(q["exponents"], s["truth"]) if s.get("truth") else math.nan)
            for s in summaries for q in (s.get("uncertainty") or {}).get("quantities", [])]
    return pd.DataFrame(rows, columns=list(UNCERTAINTY_COLUMNS))


def _at_bound_label(summary: dict | None) -> str:
    """``name=lower`` / ``name=upper`` for each parameter a run identified (those of its level, less the ones
    it held known) whose value at its best iteration lies on a bound of its range, joined by "; "."""
    if not summary or not summary.get("best"):
        return ""
    identified = [n for n in IDENTIFIED[int(summary["level"])] if n not in summary.get("known", ())]
    return "; ".join(f"{n}={side}" for n, side in at_bound(summary["best"]["parameters"], identified).items())


def generalisation_table(rows: list[dict]) -> pd.DataFrame:
    """Per run and unseen datapoint (:func:`dpsi.generalisation.comparison_rows`): the height-map distance
    (mm) of the identified parameters, the hand-picked values and no motion, and the change against the
    hand-picked values."""
    return pd.DataFrame(rows, columns=["level", "loss", "dataset", "seed", "pair", "identified_mm", "hand_picked_mm",
                                       "no_motion_mm", "change"])


def ood_table(records: list[dict]) -> pd.DataFrame:
    """Out-of-distribution height-map distances. ``records``: one per simulated (datapoint, parameter
    source) with keys motion, config (the object configuration, e.g. its datapoint id), loss, dataset
    (loss = "hand-picked" for the baseline), heightmap_mm. Adds the average over losses and datasets per
    (motion, config) for the identified parameters."""
    table = pd.DataFrame(records, columns=["motion", "config", "loss", "dataset", "heightmap_mm"])
    identified = table[table.loss != HAND_PICKED_LABEL]
    averages = (identified.groupby(["motion", "config"], sort=False)["heightmap_mm"].mean().reset_index()
                .assign(loss=AVERAGE_LABEL, dataset=AVERAGE_LABEL))
    return pd.concat([table, averages], ignore_index=True)[table.columns]


def recovery_table(summaries: list[dict]) -> pd.DataFrame:
    """For runs on the synthetic twin (summaries with a ``truth``): the relative error of every
    parameter, and of the scale-free combinations (:data:`dpsi.parameters.SCALE_FREE`), at the run's best
    iteration."""
    def values(p: dict) -> dict:
        return {**{n: p[n] for n in NAMES}, **scale_free(p)}

    rows = [dict(level=s["level"], loss=s["loss"], dataset=s["dataset"], seed=s["seed"], parameter=n,
                 truth=truth, estimate=estimate, rel_error=abs(estimate - truth) / abs(truth))
            for s in summaries if s.get("truth") and s.get("best")
            for (n, truth), estimate in zip(values(s["truth"]).items(), values(s["best"]["parameters"]).values())]
    return pd.DataFrame(rows, columns=["level", "loss", "dataset", "seed", "parameter", "truth", "estimate",
                                       "rel_error"])


def materials_table(summaries: list[dict], truths: dict[str, dict[str, float]]) -> pd.DataFrame:
    """SPEC §7.4: per material and parameter the ground truth, each seed's estimate (columns
    ``seed<s>``), the estimate of the run with the lowest validation height-map distance, its relative
    error |estimate − truth| / |truth| and that validation distance (mm, on the material's validation
    motion). Parameters in SI units.

    ``summaries``: run summaries with keys material and seed; ``truths``: material → parameter values."""
    seeds = sorted({s["seed"] for s in summaries})
    rows = []
    for (material,), runs in _group(summaries, ("material",)):
        best = _best_run(runs)
        by_seed = {r["seed"]: r["best"]["parameters"] for r in runs if r.get("best")}
        for n in NAMES:
            truth = truths[material][n]
            estimate = best["best"]["parameters"][n] if best else math.nan
            rows.append(dict(material=material, parameter=n, truth=truth,
                             **{f"seed{s}": by_seed.get(s, {}).get(n, math.nan) for s in seeds},
                             estimate=estimate, rel_error=abs(estimate - truth) / abs(truth),
                             val_heightmap_mm=_best_heightmap(best)))
    return pd.DataFrame(rows, columns=["material", "parameter", "truth", *(f"seed{s}" for s in seeds), "estimate",
                                       "rel_error", "val_heightmap_mm"])


ANY_SEED_LABEL = "any"
"""Seed of a run whose initial values do not depend on the seed (the hand-picked start)."""


def minima_table(summaries: list[dict], level: int = 1) -> pd.DataFrame:
    """SPEC §7.5: per dataset and start (random, hand-picked) and seed, the best iteration, its
    validation height-map distance (mm) and the identified parameters of ``level`` (SI units) there.
    Hand-picked runs get the seed :data:`ANY_SEED_LABEL`: their initial values ignore the seed.

    ``summaries``: run summaries with keys dataset, start and seed."""
    rows = []
    for s in sorted(summaries, key=lambda s: (s["dataset"], s["start"] != "random", s["seed"])):
        best = s.get("best") or {}
        rows.append(dict(dataset=s["dataset"], start=s["start"],
                         seed=s["seed"] if s["start"] == "random" else ANY_SEED_LABEL,
                         best_iteration=best.get("iteration", math.nan),
                         val_heightmap_mm=_best_heightmap(s),
                         **{n: best.get("parameters", {}).get(n, math.nan) for n in IDENTIFIED[level]}))
    return pd.DataFrame(rows, columns=["dataset", "start", "seed", "best_iteration", "val_heightmap_mm",
                                       *IDENTIFIED[level]])


def heightmap_losses_table(summaries: list[dict]) -> pd.DataFrame:
    """SPEC §7.7: per (loss, dataset) the five validation metrics (mm) of the run with the lowest
    validation height-map distance across seeds, with its seed and iteration, plus per loss the average
    over datasets (dataset = "average").

    ``summaries``: run summaries with keys loss, dataset and seed."""
    metrics = [f"val_{m}" for m in VALIDATION_METRICS]
    rows = []
    for (loss, dataset), runs in _group(summaries, ("loss", "dataset")):
        best = _best_run(runs)
        values = best["best"]["validation"] if best else {}
        rows.append(dict(loss=loss, dataset=dataset, seed=best["seed"] if best else math.nan,
                         best_iteration=best["best"]["iteration"] if best else math.nan,
                         **{f"val_{m}": values.get(m, math.nan) for m in VALIDATION_METRICS}))
    table = pd.DataFrame(rows, columns=["loss", "dataset", "seed", "best_iteration", *metrics])
    averages = table.groupby("loss", sort=False)[metrics].mean().reset_index().assign(dataset=AVERAGE_LABEL)
    return pd.concat([table, averages], ignore_index=True)[table.columns]


def _best_run(runs: list[dict]) -> dict | None:
    """The run summary whose best iteration has the lowest validation height-map distance (None if no
    run has a best iteration)."""
    return min((r for r in runs if r.get("best")), key=_best_heightmap, default=None)


def _best_heightmap(summary: dict | None) -> float:
    """Validation height-map distance (mm) at a run's best iteration (NaN if it has none)."""
    best = (summary or {}).get("best")
    return best["validation"]["heightmap_mm"] if best else math.nan


def _group(records: list[dict], keys: tuple[str, ...]):
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    return groups.items()


# ------------------------------------------------------------------ writing
def write_table(table: pd.DataFrame, csv_path: str | Path, caption: str = "") -> list[Path]:
    """Write ``table`` as CSV at ``csv_path`` and as Markdown (.md) and LaTeX booktabs (.tex) beside it."""
    csv_path = Path(csv_path)
    outputs = [csv_path, csv_path.with_suffix(".md"), csv_path.with_suffix(".tex")]
    texts = [table.to_csv(index=False), to_markdown(table, caption), to_latex(table, caption)]
    for path, text in zip(outputs, texts):
        with atomic_output(path) as tmp:
            tmp.write_text(text)
    return outputs


def _cell(value) -> str:
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return "–"
        return f"{value:.4g}"
    return str(value)


def to_markdown(table: pd.DataFrame, caption: str = "") -> str:
    header = "| " + " | ".join(map(str, table.columns)) + " |"
    rule = "|" + "|".join("---" for _ in table.columns) + "|"
    body = ["| " + " | ".join(_cell(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(([caption, ""] if caption else []) + [header, rule, *body]) + "\n"


def to_latex(table: pd.DataFrame, caption: str = "") -> str:
    def escape(text: str) -> str:
        return text.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("%", r"\%").replace("&", r"\&")

    columns = "l" * len(table.columns)
    lines = [r"\begin{table}[t]", r"\centering"]
    if caption:
        lines.append(rf"\caption{{{escape(caption)}}}")
    lines += [rf"\begin{{tabular}}{{{columns}}}", r"\toprule",
              " & ".join(escape(str(c)) for c in table.columns) + r" \\", r"\midrule"]
    lines += [" & ".join(escape(_cell(v)) for v in row) + r" \\" for row in table.itertuples(index=False)]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"
