"""Gradient-based identification of θ from a training set, with validation (SPEC §6).

A run is (level, loss, training datapoints, validation datapoints, seed, iterations, initial values).
Its log has one row per parameter vector θ_k, k = 0 … iterations: θ_0 is the initial guess and θ_k
the values after k Adam updates. Row k holds θ_k, the mean training loss (mm) and the screened mean
gradient at θ_k (the gradient that makes θ_{k+1}), and the five validation metrics (mm) at θ_k,
averaged over the validation datapoints. So row k ≥ 1 is the paper's record "after update k" and
row 0 adds the initial values (for figures); the best iteration is chosen among the updated rows
k ≥ 1 only, as in the paper, by the lowest validation height-map distance (``select="validation"``) or,
for a run validated on its own training datapoints, by the lowest training loss (``select="training"``).
(The last row's gradient is computed but not applied: ~1 % extra work.)

A datapoint whose simulation raises :class:`SimulationError` or whose gradient fails
:func:`dpsi.optim.screen_gradients` is skipped for that row and counted. If every training
datapoint is skipped, no update is possible and — the simulation being deterministic — none ever
will be: the run fails with :class:`IdentificationError`, giving each datapoint's cause, and writes no
summary (its rows so far stay in its state).

Output folder: ``log.csv`` (the rows), ``summary.json`` (best row, its parameters, relative errors
against a known truth) and ``state.json`` (Adam state + rows, rewritten atomically after every row).
The folder is claimed first (:func:`dpsi.output_folder.claimed`): writable, one run at a time, and
never writing over a file of these names that the run did not write.
Running again with the same arguments resumes from the last completed row and gives the same
result as an uninterrupted run; asking for more iterations than a finished run had extends it. The state
is keyed on everything that determines the result (the run's settings, a hash of the datapoints' arrays
and names, the simulator settings and the dpsi library's source code), so a state left by other inputs
or other code is never resumed; nor is one whose log and optimiser state disagree (edited by hand):
replaying the log's gradients through Adam must give its parameters and its optimiser state exactly.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path
from collections.abc import Callable, Mapping
from typing import NamedTuple, Sequence, TextIO

import numpy as np
import pandas as pd

from dpsi.datapoint import Datapoint
from dpsi.losses import LOSSES, VALIDATION_METRICS, Targets, loss_terms_by_name, validation_metrics
from dpsi.optim import Adam, screen_gradients, unusable
from dpsi.parameters import IDENTIFIED, LEVEL1_FIXED, LOWER, NAMES, UPPER, Parameters, check_known, clip, random_initial
from dpsi.files import atomic_output
from dpsi.output_folder import claimed
from dpsi.progress import Progress
from dpsi.provenance import library_checksum
from dpsi.simulation import Scene, SimulationError, Simulator, SimulatorConfig
from dpsi.uncertainty import LOG_STEP, Evaluation, UncertaintyError, assess

LOG_FILE, SUMMARY_FILE, STATE_FILE = "log.csv", "summary.json", "state.json"
STATE_VERSION = 2

METRICS = tuple(VALIDATION_METRICS)
"""The five validation metrics (mm): pcd_cd, prt_cd, pcd_emd, prt_emd, heightmap_mm."""

COLUMNS = ("iteration", *NAMES, "train_loss_mm", *(f"grad_{n}" for n in NAMES),
           *(f"val_{m}" for m in METRICS), "skipped", "val_skipped", "wall_s")
"""Log columns: parameters in their SI units, gradients in mm per parameter unit, wall time in s."""

SELECT_COLUMNS = {"validation": "val_heightmap_mm", "training": "train_loss_mm"}
"""How a run's best iteration is chosen → the log column whose lowest finite value chooses it."""


class IdentificationError(ValueError):
    """Bad run arguments, an output folder holding a different run, or a run that cannot learn (every
    training datapoint skipped)."""


def scene(dp: Datapoint) -> Scene:
    """The simulator scene of a datapoint: its particles, effector, trajectory and table."""
    return Scene(dp.particles, dp.particle_volume, dp.effector, dp.trajectory, dp.start, dp.table_z)


def targets(dp: Datapoint) -> Targets:
    """The loss targets of a datapoint."""
    return Targets(pcd=dp.pcd_target, prt=dp.prt_target, heightmap=dp.heightmap_target(),
                   heightmap_interior=dp.interior_heightmap_target())


def evaluate(simulator: Simulator, dp: Datapoint, params: Parameters,
             final: np.ndarray | None = None) -> dict[str, float]:
    """The five validation metrics (mm) of ``dp`` simulated with ``params``, or of its ``final`` particle
    positions (n, 3) in m if that simulation has already run; raises :class:`SimulationError` if the
    simulation fails."""
    if final is None:
        final = simulator.forward(scene(dp), params, keep_substeps=False)
    return validation_metrics(final, dp.pcd_target, dp.prt_target, dp.heightmap, dp.centre_xy, dp.table_z,
                              dp.particle_size)


def _nan_gradient() -> dict[str, float]:
    return {n: math.nan for n in NAMES}


class TrainingPass(NamedTuple):
    """One pass over the training set at θ: the mean loss (mm) and screened mean gradient (mm per parameter
    unit; None if all were skipped) over the datapoints kept by the SPEC §6 rules, the number skipped, the
    final particle positions (n, 3) in m and the loss's terms (mm, :class:`dpsi.losses.LossTerms`) of each
    datapoint whose simulation succeeded, keyed by ``id()`` of the datapoint object (so that validating on the
    same objects needs no second simulation), and why each skipped datapoint was skipped ("<id>: <cause>")."""

    loss_mm: float
    gradient: dict[str, float] | None
    skipped: int
    finals: dict[int, np.ndarray]
    terms: dict[int, np.ndarray]
    causes: tuple[str, ...] = ()


def training_gradient(simulator: Simulator, training: Sequence[Datapoint], params: Parameters,
                      loss: str) -> TrainingPass:
    """Simulate every training datapoint with ``params`` and back-propagate ``loss`` (see :class:`TrainingPass`)."""
    loss_fn = loss_terms_by_name(loss)
    values, gradients, finals, terms, causes = [], [], {}, {}, []
    for dp in training:
        try:
            final = simulator.forward(scene(dp), params)
            finals[id(dp)] = final
            value, d_positions, terms[id(dp)] = loss_fn(final, targets(dp))
            gradient = simulator.backward(d_positions)
            cause = unusable(gradient, value)
        except SimulationError as err:
            value, gradient, cause = math.nan, _nan_gradient(), f"simulation failed: {err}"
        values.append(value)
        gradients.append(gradient)
        causes.append(cause)
    screened = screen_gradients(gradients, values)
    kept = [v for v, cause in zip(values, causes) if cause is None]
    return TrainingPass(float(np.mean(kept)) if kept else math.nan, screened.gradient, screened.skipped, finals,
                        terms, tuple(f"{dp.id}: {cause}" for dp, cause in zip(training, causes) if cause))


def validation(simulator: Simulator, datapoints: Sequence[Datapoint], params: Parameters,
               simulated: Mapping[int, np.ndarray] | None = None) -> tuple[dict[str, float], int]:
    """The five metrics (mm) averaged over the datapoints whose simulation succeeds (NaN if none does),
    and the number that failed. ``simulated``: final positions already computed at ``params``, keyed by
    ``id()`` of the datapoint object (:attr:`TrainingPass.finals`); the others are simulated here."""
    simulated = simulated or {}
    rows = []
    for dp in datapoints:
        try:
            rows.append(evaluate(simulator, dp, params, simulated.get(id(dp))))
        except SimulationError:
            pass
    means = {m: float(np.mean([r[m] for r in rows])) if rows else math.nan for m in METRICS}
    return means, len(datapoints) - len(rows)


def uncertainty_at(simulator: Simulator, training: Sequence[Datapoint], params: Parameters, loss: str,
                   free: Sequence[str], step: float = LOG_STEP) -> dict:
    """The :func:`dpsi.uncertainty.assess` block of the training ``loss`` at ``params`` over the ``free``
    parameters (central-difference ``step`` in log units): two gradient passes over the training set per free
    parameter beside the one at ``params``;
    raises :class:`~dpsi.uncertainty.UncertaintyError` if a simulation or gradient fails on the way."""
    def evaluate(x: np.ndarray) -> Evaluation:
        at = params.replace(**clip({n: math.exp(v) for n, v in zip(free, x)}))
        trained = training_gradient(simulator, training, at, loss)
        if trained.gradient is None or trained.skipped:
            raise UncertaintyError(f"{trained.skipped} training datapoint(s) failed at {at.as_dict()}")
        return Evaluation(trained.loss_mm, np.array([trained.gradient[n] * getattr(at, n) for n in free]),
                          tuple(trained.terms[id(dp)] for dp in training))

    start = time.perf_counter()
    log = lambda bounds: [math.log(bounds[n]) for n in free]  # noqa: E731
    block = assess(free, log(params.as_dict()), log(LOWER), log(UPPER), evaluate, step)
    return {**block, "wall_s": time.perf_counter() - start}


def check_run(level: int, loss: str, training: Sequence[Datapoint], validation_set: Sequence[Datapoint],
              seed: int, iterations: int, initial: Parameters | None, config: SimulatorConfig) -> Parameters:
    """Validate the arguments of a run (no simulation) and return its initial θ: ``initial`` (range-checked,
    with the level-1 frictions replaced by :data:`LEVEL1_FIXED`) or random from ``seed``."""
    if level not in IDENTIFIED:
        raise IdentificationError(f"level must be one of {sorted(IDENTIFIED)}, got {level!r}")
    if loss not in LOSSES:
        raise IdentificationError(f"unknown loss {loss!r}; known losses are {list(LOSSES)}")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise IdentificationError(f"iterations must be a positive integer, got {iterations!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise IdentificationError(f"seed must be a non-negative integer, got {seed!r}")
    emd_targets = {"pcd_emd": ("pcd_target",), "prt_emd": ("prt_target",)}.get(loss, ())
    for name, dataset, fields in (("training", training, emd_targets),
                                  ("validation", validation_set, ("pcd_target", "prt_target"))):
        if len(dataset) == 0:
            raise IdentificationError(f"the {name} dataset is empty")
        for dp in dataset:
            _check_datapoint(dp, name, config, fields)
    if initial is None:
        return random_initial(seed, level)
    try:
        initial.check_range()
    except ValueError as err:
        raise IdentificationError(f"initial value: {err}") from None
    return initial.replace(**LEVEL1_FIXED) if level == 1 else initial


def _check_datapoint(dp: Datapoint, dataset: str, config: SimulatorConfig, emd_targets: Sequence[str]) -> None:
    """Raise naming ``dp`` if the simulator cannot hold it (too many particles or steps, or it leaves the
    simulated box), steps at another length than the simulator, or one of its ``emd_targets`` (fields
    measured by an earth mover's distance) is empty or has more points than the particles; the messages
    name the option to change."""
    where = f"{dataset} datapoint {dp.id!r}"
    n = len(dp.particles)
    if n > config.max_particles:
        raise IdentificationError(f"{where} has {n} particles, more than the simulator's max_particles="
                                  f"{config.max_particles}; lower the particle density or raise max_particles "
                                  "(--max-particles, or simulator.max_particles in the workflow config)")
    if not math.isclose(dp.trajectory.dt, config.step_dt):
        raise IdentificationError(f"{where} has trajectory steps of {dp.trajectory.dt} s, the simulator "
                                  f"{config.step_dt} s; resample the trajectory to the simulator's step")
    if dp.trajectory.n_steps > config.max_steps:
        raise IdentificationError(f"{where} has {dp.trajectory.n_steps} steps, more than the simulator's "
                                  f"max_steps={config.max_steps}")
    try:
        config.check_box(scene(dp))
    except SimulationError as err:
        raise IdentificationError(f"{where}: {err}") from None
    for field in emd_targets:
        k = len(getattr(dp, field))
        if not 0 < k <= n:
            raise IdentificationError(f"{where}: {field} has {k} points; the earth mover's distance needs "
                                      f"between 1 and the particle count {n}: raise the particle density (now "
                                      f"{1.0 / dp.particle_volume:.3g} particles/m³; --density, or "
                                      "reconstruction.density in the workflow config)")


def hold_known(initial: Parameters, known: Mapping[str, float] | None, level: int) -> Parameters:
    """``initial`` with the ``known`` parameters (name → value in SI, e.g. a weighed sample's density)
    set; they must be identified at ``level`` (the others are fixed anyway), in range, and leave at least
    one parameter to identify."""
    known = dict(known or {})
    try:
        check_known(known, level)
    except ValueError as err:
        raise IdentificationError(str(err)) from None
    try:
        return initial.replace(**{n: float(v) for n, v in known.items()})
    except ValueError as err:
        raise IdentificationError(f"known value: {err}") from None


def _fingerprint(level, loss, seed, initial: Parameters, training, validation_set, known=()) -> dict:
    """The run's settings, named in an error when a stored state differs from them."""
    describe = lambda dps: [[dp.id, len(dp.particles), dp.trajectory.n_steps] for dp in dps]  # noqa: E731
    return {"level": level, "loss": loss, "seed": seed, "initial": initial.as_dict(), "known": sorted(known),
            "training": describe(training), "validation": describe(validation_set)}


def _feed(digest, value) -> None:
    """Add ``value`` (array, dataclass, mapping, sequence or scalar) to ``digest``, exactly."""
    if isinstance(value, np.ndarray):
        digest.update(f"{value.dtype.str}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            digest.update(field.name.encode())
            _feed(digest, getattr(value, field.name))
    elif isinstance(value, dict):
        for key in sorted(value):
            _feed(digest, key)
            _feed(digest, value[key])
    elif isinstance(value, (list, tuple)):
        digest.update(f"[{len(value)}".encode())
        for item in value:
            _feed(digest, item)
    else:
        digest.update(repr(value).encode())


def inputs_key(training: Sequence[Datapoint], validation_set: Sequence[Datapoint], config) -> str:
    """SHA-256 of what determines a run's result besides its settings: every field of every training
    and validation datapoint (particles, particle volume, trajectory, effector, targets, …), the simulator
    settings ``config`` and the dpsi library's source code."""
    digest = hashlib.sha256()
    _feed(digest, [list(training), list(validation_set), config, library_checksum()])
    return digest.hexdigest()


def _is_state(path: Path) -> bool:
    """Whether ``path`` holds an identification state of any version (a JSON object with a run and a log):
    a file this module wrote, even before output folders recorded their files."""
    try:
        state = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(state, dict) and {"version", "run", "log"} <= set(state)


def _load_state(path: Path, fingerprint: dict, key: str) -> dict | None:
    """The state stored at ``path`` (None if there is none), if it belongs to this run."""
    if not path.exists():
        return None
    try:
        state = json.loads(path.read_text())
        stored = state["run"]
        state["adam"], state["log"]
    except (ValueError, KeyError, TypeError) as err:
        raise IdentificationError(f"{path} is not a readable identification state ({err}); "
                                  "delete it to restart") from None
    if state.get("version") != STATE_VERSION:
        raise IdentificationError(f"{path} has state version {state.get('version')}, expected {STATE_VERSION}; "
                                  "delete it to restart")
    differ = sorted(k for k in fingerprint if stored.get(k) != fingerprint[k])
    if differ:
        raise IdentificationError(f"{path} belongs to a different run (differs in {differ}); "
                                  "use another output folder or delete it")
    if state.get("inputs") != key:
        raise IdentificationError(f"{path} belongs to a run of other inputs (datapoint arrays, targets, "
                                  "effectors, particle volume, simulator settings or dpsi library code differ); "
                                  "use another output folder or delete it")
    return state


def _replay(path: Path, state: dict, adam: Adam, initial: Parameters) -> list[dict]:
    """The rows of a stored ``state``, after replaying their gradients through ``adam`` (fresh, at
    ``initial``): every row's parameters and the stored optimiser state must be what the replay gives,
    exactly, or the state (edited by hand, or damaged) is refused."""
    def refuse(problem: str):
        raise IdentificationError(f"{path} cannot be resumed: {problem}; was it edited? Delete it to restart")

    rows = state["log"]
    if not isinstance(rows, list) or not rows:
        refuse("its log has no rows")
    for k, row in enumerate(rows):
        if not isinstance(row, dict) or set(row) != set(COLUMNS) or row["iteration"] != k:
            refuse(f"its log row {k} is not row {k} of an identification log")
        if k:
            gradient = _gradient_of(rows[k - 1])
            if gradient is None:
                refuse(f"its log row {k - 1} has no gradient, yet an update follows it")
            adam.step(gradient)
        expected = initial.replace(**adam.values).as_dict()
        if any(row[n] != expected[n] for n in NAMES):
            refuse(f"the parameters of its log row {k} are not those the log's gradients give "
                   f"({ {n: row[n] for n in adam.values} } instead of { {n: expected[n] for n in adam.values} })")
    if state["adam"] != adam.state():
        refuse(f"its optimiser state disagrees with its log (Adam after {state['adam'].get('iteration')} updates "
               f"at {state['adam'].get('values')}; the log's {len(rows) - 1} updates give {adam.values})"
               if isinstance(state["adam"], dict) else "its optimiser state is not a mapping")
    return rows


def _resume(path: Path, fingerprint: dict, key: str, fresh: Callable[[], Adam], initial: Parameters,
            restart: bool, note: Callable[[str], None]) -> tuple[Adam, list[dict], dict | None]:
    """The optimiser, rows and uncertainty block (None if not measured) of the run's stored state at
    ``path`` (a ``fresh`` optimiser, no rows and None if there is none); ``restart``: discard a state that
    cannot be resumed, saying why with ``note``, instead of refusing it."""
    try:
        state = _load_state(path, fingerprint, key)
        adam = fresh()
        if not state:
            return adam, [], None
        return adam, _replay(path, state, adam, initial), state.get("uncertainty")
    except IdentificationError as err:
        if not restart:
            raise
        note(f"starting afresh: {err}")
        path.unlink()
        return fresh(), [], None


def _save_state(path: Path, fingerprint: dict, key: str, adam: Adam, rows: list[dict],
                uncertainty: dict | None = None) -> None:
    state = {"version": STATE_VERSION, "run": fingerprint, "inputs": key, "adam": adam.state(), "log": rows}
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(state if uncertainty is None else {**state, "uncertainty": uncertainty}))


def _row(k: int, params: Parameters, loss_mm: float, gradient: dict, skipped: int,
         metrics: dict, val_skipped: int, wall_s: float) -> dict:
    return {"iteration": k, **params.as_dict(), "train_loss_mm": loss_mm,
            **{f"grad_{n}": gradient[n] for n in NAMES}, **{f"val_{m}": metrics[m] for m in METRICS},
            "skipped": skipped, "val_skipped": val_skipped, "wall_s": wall_s}


def _gradient_of(row: dict) -> dict[str, float] | None:
    gradient = {n: row[f"grad_{n}"] for n in NAMES}
    return None if any(math.isnan(g) for g in gradient.values()) else gradient


def summarise(rows: Sequence[dict], fingerprint: dict, iterations: int, truth: Parameters | None,
              labels: Mapping | None = None, select: str = "validation") -> dict:
    """The run summary: its ``labels`` (what the run is, for the reports), best row (lowest finite value of
    the :data:`SELECT_COLUMNS` column of ``select`` among the updated rows k ≥ 1; None if none has one:
    row 0 holds the initial values, which are never reported as identified), its parameters and metrics,
    the final parameters and, given ``truth``, the relative error |best − truth| / |truth| of each
    parameter."""
    column = _select_column(select)
    candidates = [r for r in rows[1:] if r[column] is not None and math.isfinite(r[column])]
    best = min(candidates, key=lambda r: r[column]) if candidates else None
    completed = rows[-1]["iteration"]
    out = {**fingerprint, "labels": dict(labels or {}), "selected_by": select, "iterations": iterations,
           "completed_iterations": completed,
           "skipped_total": int(sum(r["skipped"] for r in rows)),
           "wall_s": float(sum(r["wall_s"] for r in rows)),
           "final": {"iteration": completed, "parameters": {n: rows[-1][n] for n in NAMES}},
           "best": None if best is None else {
               "iteration": best["iteration"], "parameters": {n: best[n] for n in NAMES},
               "validation": {m: best[f"val_{m}"] for m in METRICS}}}
    if truth is not None:
        out["truth"] = truth.as_dict()
        out["relative_error"] = None if best is None else {
            n: abs(best[n] - getattr(truth, n)) / abs(getattr(truth, n)) for n in NAMES}
    return out


def _select_column(select: str) -> str:
    if select not in SELECT_COLUMNS:
        raise IdentificationError(f"unknown choice of the best iteration {select!r}; use one of {list(SELECT_COLUMNS)}")
    return SELECT_COLUMNS[select]


def identify(out_dir: str | Path, level: int, loss: str, training: Sequence[Datapoint],
             validation_set: Sequence[Datapoint], seed: int = 0, iterations: int = 100,
             initial: Parameters | None = None, truth: Parameters | None = None,
             simulator: Simulator | None = None, progress: TextIO | None = None,
             restart_if_different: bool = False, labels: Mapping | None = None,
             known: Mapping[str, float] | None = None, select: str = "validation",
             uncertainty: bool = False) -> dict:
    """Run (or resume) an identification into ``out_dir`` and return its summary (see module doc).

    ``initial``: the starting θ (default random from ``seed`` in the level's ranges; at level 1 its frictions
    are replaced by :data:`~dpsi.parameters.LEVEL1_FIXED`); ``truth``: known
    parameters for the relative errors; ``simulator``: the process's simulator (default: one with
    :class:`SimulatorConfig` defaults); ``progress``: stream for progress messages (default stderr);
    ``restart_if_different``: discard a state file left by a different run (other settings, datapoints,
    simulator settings or library code) instead of refusing to continue it; ``labels``: what the run is
    (level, loss, dataset, seed, start, material), written into its summary for the reports; ``known``:
    parameters held at given values instead of identified (see :func:`hold_known`; multiplying E, ρ and
    σ_y by one factor changes no motion, so a measured ρ is what makes E and σ_y identifiable). A validation
    datapoint that is the same object as a training one is validated on its training simulation.
    ``select``: how the best iteration is chosen (:data:`SELECT_COLUMNS`); it changes only the summary.
    ``uncertainty``: add what the data determine at the best iteration (:func:`uncertainty_at`, kept in the
    state, so that a finished run asked again does not measure it again) as the summary's ``uncertainty``.
    """
    _select_column(select)
    config = simulator.config if simulator is not None else SimulatorConfig()
    initial = hold_known(check_run(level, loss, training, validation_set, seed, iterations, initial, config),
                         known, level)
    held = tuple(known or ())
    fingerprint = _fingerprint(level, loss, seed, initial, training, validation_set, held)
    key = inputs_key(training, validation_set, config)
    files = (STATE_FILE, LOG_FILE, SUMMARY_FILE)
    with (claimed(out_dir, files, "dpsi identify", progress, adopt=_is_state) as out_dir,
          Progress(iterations, f"identify L{level} {loss} seed {seed}", progress) as bar):
        state_file = out_dir / STATE_FILE
        adam, rows, block = _resume(state_file, fingerprint, key, lambda: Adam.for_level(initial, level, held), initial,
                             restart_if_different, bar.message)
        if rows and rows[-1]["iteration"] > iterations:
            raise IdentificationError(f"{state_file} already has {rows[-1]['iteration']} iterations, "
                                      f"more than the {iterations} asked for")
        while not rows or rows[-1]["iteration"] < iterations:
            if rows:
                adam.step(_gradient_of(rows[-1]))
            if simulator is None:
                simulator = Simulator(config)
            start = time.perf_counter()
            params = initial.replace(**adam.values)
            trained = training_gradient(simulator, training, params, loss)
            if trained.gradient is None:
                raise IdentificationError(
                    f"nothing to learn from at iteration {len(rows)}: every training datapoint was skipped "
                    f"(parameters {params.as_dict()}): " + "; ".join(trained.causes))
            metrics, val_skipped = validation(simulator, validation_set, params, trained.finals)
            rows.append(_row(len(rows), params, trained.loss_mm, trained.gradient, trained.skipped, metrics,
                             val_skipped, time.perf_counter() - start))
            _save_state(state_file, fingerprint, key, adam, rows, block)
            row = rows[-1]
            bar.update(row["iteration"], f"loss {row['train_loss_mm']:.1f} mm, val height map "
                                         f"{row['val_heightmap_mm']:.1f} mm, skipped {row['skipped']}, "
                                         f"{row['wall_s']:.1f} s")
        with atomic_output(out_dir / LOG_FILE) as tmp:
            pd.DataFrame(rows, columns=list(COLUMNS)).to_csv(tmp, index=False)
        summary = summarise(rows, fingerprint, iterations, truth, labels, select)
        if uncertainty and summary["best"] is not None:
            if not block or block["iteration"] != summary["best"]["iteration"]:
                bar.message(f"measuring what the data determine at iteration {summary['best']['iteration']}")
                block = {"iteration": summary["best"]["iteration"]}
                try:
                    block.update(uncertainty_at(simulator or Simulator(config), training,
                                                Parameters.checked(**summary["best"]["parameters"]), loss,
                                                [n for n in IDENTIFIED[level] if n not in held]))
                except (UncertaintyError, SimulationError) as err:
                    block["error"] = str(err)
                _save_state(state_file, fingerprint, key, adam, rows, block)
            summary["uncertainty"] = block
        with atomic_output(out_dir / SUMMARY_FILE) as tmp:
            tmp.write_text(json.dumps(summary, indent=2) + "\n")
    return summary


__all__ = ["LOG_FILE", "SUMMARY_FILE", "STATE_FILE", "METRICS", "COLUMNS", "SELECT_COLUMNS", "IdentificationError",
           "scene", "targets", "inputs_key", "evaluate", "TrainingPass", "training_gradient", "validation", "uncertainty_at",
           "check_run",
           "hold_known", "summarise", "identify"]
