"""Identification on a tiny synthetic problem: 245-particle blocks poked for 15 steps on a coarse grid,
with "after" targets simulated from known parameters."""

import dataclasses
import io
import json
import math
import os
import socket
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from conftest import assert_same_numbers
from dpsi.datapoint import Datapoint
from dpsi.heightmap import height_map
from dpsi import identification
from dpsi.effectors import by_name
from dpsi.identification import (COLUMNS, LOG_FILE, STATE_FILE, SUMMARY_FILE, IdentificationError, identify,
                                  inputs_key, scene)
from dpsi.motions import Trajectory
from dpsi.output_folder import LOCK_FILE, FolderError
from dpsi.parameters import HAND_PICKED, LEVEL1_FIXED, Parameters
from dpsi.reconstruction.filling import pcd_target
from dpsi.simulation import SimulationError, Simulator, SimulatorConfig

SPACING = 0.004
CONFIG = SimulatorConfig(dx=0.006, width=0.08, height=0.05, max_particles=1000, max_steps=40)
TRUTH = HAND_PICKED.replace(E=5e4, yield_stress=3e3, **LEVEL1_FIXED)


def block() -> np.ndarray:
    """A 2.8 × 2.8 × 2 cm block of particles on the table z = 0."""
    xy = np.arange(-0.012, 0.0121, SPACING)
    z = np.arange(SPACING / 2, 0.02, SPACING)
    return np.stack(np.meshgrid(xy, xy, z, indexing="ij"), -1).reshape(-1, 3)


def poke(depth: float) -> Trajectory:
    """Down by ``depth`` m in 10 steps, then back up by half of it in 5."""
    z = np.concatenate([np.linspace(0.0, -depth, 11), -depth + np.linspace(0.0, depth / 2, 6)[1:]])
    return Trajectory(np.column_stack([np.zeros((len(z), 2)), z]), np.zeros(len(z)))


def synthetic(simulator: Simulator, effector: str, depth: float) -> Datapoint:
    """A datapoint whose targets come from simulating the block with :data:`TRUTH`."""
    particles = block()
    centre = particles[:, :2].mean(axis=0)
    start = [*centre, particles[:, 2].max() + SPACING / 2]
    dp = Datapoint(effector, "poke", by_name(effector), particles, SPACING**3, poke(depth), np.array(start), 0.0,
                   particles, particles, np.zeros((32, 32)), centre)
    after = simulator.forward(scene(dp), TRUTH)
    dp.prt_target, dp.pcd_target, dp.heightmap = after, pcd_target(after), height_map(after, centre)
    return dp


@pytest.fixture(scope="module")
def simulator():
    return Simulator(CONFIG)


@pytest.fixture(scope="module")
def problem(simulator):
    """(training, validation) datapoints."""
    return ([synthetic(simulator, "round", 0.008), synthetic(simulator, "rectangle", 0.008)],
            [synthetic(simulator, "cylinder", 0.006)])


def test_recovers_young_modulus_and_yield_stress(simulator, problem, tmp_path):
    start = TRUTH.replace(E=2e4, yield_stress=8e3)
    summary = identify(tmp_path, 1, "prt_cd", *problem, iterations=30, initial=start, truth=TRUTH,
                       simulator=simulator, progress=io.StringIO())
    log = pd.read_csv(tmp_path / LOG_FILE)
    assert list(log.columns) == list(COLUMNS) and list(log.iteration) == list(range(31))
    assert (log.skipped == 0).all() and (log.mu_table == LEVEL1_FIXED["mu_table"]).all()
    assert log.train_loss_mm.iloc[-5:].min() < 0.25 * log.train_loss_mm.iloc[0]
    for name in ("E", "yield_stress"):
        initial_error = abs(getattr(start, name) - getattr(TRUTH, name))
        assert abs(log[name].iloc[-1] - getattr(TRUTH, name)) < 0.5 * initial_error, name
        assert summary["relative_error"][name] < 0.6 * initial_error / getattr(TRUTH, name), name
    best = log.loc[log.iteration >= 1, "val_heightmap_mm"].idxmin()
    assert summary["best"]["iteration"] == best
    assert summary["best"]["parameters"]["E"] == log.E[best]


def test_a_known_parameter_is_held_and_the_others_identified(simulator, problem, tmp_path):
    summary = identify(tmp_path, 1, "prt_cd", *problem, iterations=2, initial=HAND_PICKED, truth=TRUTH,
                       simulator=simulator, progress=io.StringIO(), known={"rho": 1250.0})
    log = pd.read_csv(tmp_path / LOG_FILE)
    assert (log.rho == 1250.0).all() and log.E.nunique() == 3 and log.yield_stress.nunique() == 3
    assert summary["known"] == ["rho"]
    with pytest.raises(IdentificationError, match=r"different run.*\['known'\]"):  # a state is not reused
        identify(tmp_path, 1, "prt_cd", *problem, iterations=2, initial=HAND_PICKED.replace(rho=1250.0),
                 simulator=simulator, progress=io.StringIO())


def test_what_the_data_determine_is_measured_at_the_best_iteration_and_kept_in_the_state(simulator, problem,
                                                                                         tmp_path, monkeypatch):
    run = dict(level=1, loss="prt_cd", training=problem[0], validation_set=problem[1], iterations=2,
               initial=HAND_PICKED, simulator=simulator, progress=io.StringIO(), known={"rho": 1250.0},
               uncertainty=True)
    summary = identify(tmp_path, **run)
    block = summary["uncertainty"]
    assert block["iteration"] == summary["best"]["iteration"] and block["free"] == ["E", "nu", "yield_stress"]
    assert block["evaluations"] == 7 and "error" not in block
    estimates = {q["quantity"]: q["estimate"] for q in block["quantities"]}
    assert estimates["E"] == pytest.approx(summary["best"]["parameters"]["E"])
    assert estimates["yield_stress/E"] == pytest.approx(summary["best"]["parameters"]["yield_stress"] / estimates["E"])
    assert json.loads((tmp_path / "summary.json").read_text())["uncertainty"] == block
    monkeypatch.setattr(identification, "uncertainty_at", lambda *args, **kwargs: pytest.fail("measured again"))
    assert identify(tmp_path, **run)["uncertainty"] == block  # a finished run asked again reuses its block
    assert "uncertainty" not in identify(tmp_path, **{**run, "uncertainty": False})


class Interrupt(io.StringIO):
    """A progress stream that raises KeyboardInterrupt on its ``after``-th line, i.e. right after a row
    has been saved."""

    def __init__(self, after: int):
        super().__init__()
        self.after = after

    def write(self, text):
        self.after -= 1
        if self.after == 0:
            raise KeyboardInterrupt
        return super().write(text)


def test_a_validation_datapoint_that_is_a_training_one_is_not_simulated_again(simulator, problem, tmp_path,
                                                                             monkeypatch):
    training = problem[0]
    forwards = []
    simulate = simulator.forward
    monkeypatch.setattr(simulator, "forward", lambda *args, **kwargs: forwards.append(1) or simulate(*args, **kwargs))
    run = dict(level=1, loss="prt_cd", iterations=1, initial=HAND_PICKED, simulator=simulator, progress=io.StringIO())
    identify(tmp_path / "same", training=training, validation_set=training, **run)
    assert len(forwards) == 2 * len(training)  # rows 0 and 1: one simulation per datapoint each
    forwards.clear()
    copies = [dataclasses.replace(dp) for dp in training]
    identify(tmp_path / "copies", training=training, validation_set=copies, **run)
    assert len(forwards) == 4 * len(training)
    same, separate = (pd.read_csv(tmp_path / name / LOG_FILE) for name in ("same", "copies"))
    metrics = [c for c in COLUMNS if c.startswith("val_") and c != "val_skipped"]
    assert np.allclose(same[metrics], separate[metrics], rtol=1e-12, atol=0)
    assert same.val_heightmap_mm.gt(0).all()


def _without_wall_time(folder):
    return [{k: v for k, v in row.items() if k != "wall_s"}
            for row in json.loads((folder / STATE_FILE).read_text())["log"]]


def test_resumed_run_equals_uninterrupted_run(simulator, problem, tmp_path):
    run = dict(level=2, loss="prt_emd", training=problem[0], validation_set=problem[1], seed=3,
               simulator=simulator, progress=io.StringIO())
    whole = identify(tmp_path / "whole", iterations=4, **run)

    identify(tmp_path / "parts", iterations=2, **run)  # a shorter run, then extended
    with pytest.raises(KeyboardInterrupt):  # killed after row 3 is saved
        identify(tmp_path / "parts", iterations=4, **{**run, "progress": Interrupt(after=1)})
    assert len(_without_wall_time(tmp_path / "parts")) == 4
    parts = identify(tmp_path / "parts", iterations=4, **run)

    assert_same_numbers([parts["final"], parts["best"]], [whole["final"], whole["best"]])
    assert_same_numbers(_without_wall_time(tmp_path / "parts"), _without_wall_time(tmp_path / "whole"))
    assert whole["final"]["iteration"] == 4 and whole["initial"]["E"] != whole["final"]["parameters"]["E"]

    with pytest.raises(IdentificationError, match=r"different run.*\['loss'\]"):
        identify(tmp_path / "parts", iterations=4, **{**run, "loss": "prt_cd"})
    with pytest.raises(IdentificationError, match="already has 4 iterations"):
        identify(tmp_path / "parts", iterations=3, **run)


def _shifted(dp: Datapoint, **change) -> Datapoint:
    return dataclasses.replace(dp, **change)


@pytest.mark.parametrize("change", [
    lambda dp: _shifted(dp, prt_target=dp.prt_target + [0.0, 0.0, 1e-6]),
    lambda dp: _shifted(dp, pcd_target=dp.pcd_target[:-1]),
    lambda dp: _shifted(dp, heightmap=dp.heightmap + 1e-9),
    lambda dp: _shifted(dp, effector=by_name("rectangle")),
    lambda dp: _shifted(dp, particle_volume=dp.particle_volume * 2),
    lambda dp: _shifted(dp, particles=dp.particles + [1e-9, 0.0, 0.0]),
    lambda dp: _shifted(dp, trajectory=poke(0.009)),
    lambda dp: _shifted(dp, start=dp.start + [0.0, 0.0, 1e-4]),
    lambda dp: _shifted(dp, table_z=1e-4),
])
def test_inputs_key_covers_every_datapoint_field(problem, change):
    training, validation_set = problem
    key = inputs_key(training, validation_set, CONFIG)
    assert inputs_key([dataclasses.replace(dp) for dp in training], validation_set, CONFIG) == key
    assert inputs_key([change(training[0]), training[1]], validation_set, CONFIG) != key
    assert inputs_key(training, [change(validation_set[0])], CONFIG) != key


def test_inputs_key_covers_simulator_settings_and_library_code(problem, monkeypatch):
    key = inputs_key(*problem, CONFIG)
    assert inputs_key(*problem, dataclasses.replace(CONFIG, cfl=0.6)) != key
    monkeypatch.setattr(identification, "library_checksum", lambda: "edited losses.py")
    assert inputs_key(*problem, CONFIG) != key


def test_state_of_other_inputs_or_code_is_not_resumed(simulator, problem, tmp_path, monkeypatch):
    """A state left by other targets, another effector or other library code is refused, or (the
    workflow's mode) discarded: the run then equals a fresh run of the new inputs."""
    training, validation_set = problem
    run = dict(level=1, loss="prt_cd", validation_set=validation_set, iterations=1, simulator=simulator)
    identify(tmp_path / "run", training=training, progress=io.StringIO(), **run)
    first_loss = pd.read_csv(tmp_path / "run" / LOG_FILE).train_loss_mm[0]
    moved = [_shifted(training[0], prt_target=training[0].prt_target + [0.0, 0.0, 0.002]), training[1]]
    for other in (moved, [_shifted(training[0], effector=by_name("cylinder")), training[1]]):
        with pytest.raises(IdentificationError, match="other inputs"):
            identify(tmp_path / "run", training=other, progress=io.StringIO(), **run)
    with monkeypatch.context() as patch:
        patch.setattr(identification, "library_checksum", lambda: "edited losses.py")
        with pytest.raises(IdentificationError, match="dpsi library code"):
            identify(tmp_path / "run", training=training, progress=io.StringIO(), **run)

    restarted = identify(tmp_path / "run", training=moved, progress=io.StringIO(), restart_if_different=True, **run)
    fresh = identify(tmp_path / "fresh", training=moved, progress=io.StringIO(), **run)
    assert_same_numbers(_without_wall_time(tmp_path / "run"), _without_wall_time(tmp_path / "fresh"))
    assert_same_numbers([restarted["final"], restarted["best"]["validation"]],
                        [fresh["final"], fresh["best"]["validation"]])
    assert pd.read_csv(tmp_path / "run" / LOG_FILE).train_loss_mm[0] > first_loss + 0.5  # the moved target


def _failing(*args, **kwargs):
    raise SimulationError("unstable")


def test_a_run_whose_training_simulations_all_fail_fails_with_their_cause(problem, tmp_path):
    broken = SimpleNamespace(config=CONFIG, forward=_failing, backward=_failing)
    with pytest.raises(IdentificationError, match=r"nothing to learn from at iteration 0: every training datapoint "
                                                  r"was skipped.*round: simulation failed: unstable; rectangle: "
                                                  r"simulation failed: unstable"):
        identify(tmp_path, 1, "prt_cd", *problem, iterations=5, simulator=broken, progress=io.StringIO())
    assert not (tmp_path / LOG_FILE).exists() and not (tmp_path / SUMMARY_FILE).exists()


def test_a_run_that_can_no_longer_learn_fails_and_keeps_its_rows(simulator, problem, tmp_path):
    """Unstable from iteration 2 on: rows 0 and 1 stay in the state, no summary claims a result."""
    calls = []

    def forward(*args, **kwargs):
        calls.append(1)
        if len(calls) > 2 * len(problem[0]):
            raise SimulationError("step 3 of 15 produced NaN or inf")
        return simulator.forward(*args, **kwargs)

    flaky = SimpleNamespace(config=CONFIG, forward=forward, backward=simulator.backward)
    with pytest.raises(IdentificationError, match="at iteration 2: .*round: simulation failed: step 3 of 15"):
        identify(tmp_path, 1, "prt_cd", problem[0], problem[0], iterations=3, initial=HAND_PICKED,
                 simulator=flaky, progress=io.StringIO())
    assert [row["iteration"] for row in json.loads((tmp_path / STATE_FILE).read_text())["log"]] == [0, 1]
    assert not (tmp_path / SUMMARY_FILE).exists()


def test_gradients_screened_out_everywhere_are_a_cause_too(problem, tmp_path):
    flat = SimpleNamespace(config=CONFIG, forward=lambda scene, params: scene.particles,
                           backward=lambda d: dict.fromkeys(HAND_PICKED.as_dict(), 0.0))
    with pytest.raises(IdentificationError, match=r"round: its gradient is zero for \['E', 'nu'"):
        identify(tmp_path, 1, "prt_cd", *problem, iterations=1, simulator=flat, progress=io.StringIO())


def test_files_in_the_output_folder_that_the_run_did_not_write_are_kept(problem, tmp_path):
    (tmp_path / LOG_FILE).write_text("a log of my own\n")
    (tmp_path / "notes.txt").write_text("mine\n")
    untouchable = SimpleNamespace(config=CONFIG, forward=_failing, backward=_failing)
    with pytest.raises(FolderError, match=f"holds {LOG_FILE}, which dpsi identify did not write"):
        identify(tmp_path, 1, "prt_cd", *problem, simulator=untouchable, progress=io.StringIO())
    assert (tmp_path / LOG_FILE).read_text() == "a log of my own\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [LOG_FILE, "notes.txt"]


def test_a_second_run_on_the_same_folder_is_refused_before_simulating(problem, tmp_path):
    """The first run holds the folder while it simulates; the second, started meanwhile, is refused."""
    second = {}

    def forward_starting_a_second_run(*args, **kwargs):
        untouchable = SimpleNamespace(config=CONFIG, forward=_failing, backward=_failing)
        with pytest.raises(FolderError) as refused:
            identify(tmp_path, 1, "prt_cd", *problem, simulator=untouchable, progress=io.StringIO())
        second["message"] = str(refused.value)
        raise SimulationError("stop the first run too")

    first = SimpleNamespace(config=CONFIG, forward=forward_starting_a_second_run, backward=_failing)
    with pytest.raises(IdentificationError, match="nothing to learn"):
        identify(tmp_path, 1, "prt_cd", *problem, simulator=first, progress=io.StringIO())
    assert second["message"].startswith(f"output folder {tmp_path} is in use by another run (dpsi identify, "
                                        f"process {os.getpid()} on host {socket.gethostname()}, started ")
    assert not (tmp_path / LOCK_FILE).exists()


def _edit_state(folder, edit):
    state = json.loads((folder / STATE_FILE).read_text())
    edit(state)
    (folder / STATE_FILE).write_text(json.dumps(state))


@pytest.mark.parametrize("edit, message", [
    (lambda s: s["adam"]["values"].update(E=s["adam"]["values"]["E"] + 1.0), "its optimiser state disagrees with its log"),
    (lambda s: s["adam"].update(iteration=1), "its optimiser state disagrees with its log"),
    (lambda s: s["log"][1].update(E=s["log"][1]["E"] * 2), "the parameters of its log row 1 are not those"),
    (lambda s: s["log"][0].update(grad_E=s["log"][0]["grad_E"] * 2), "the parameters of its log row 1 are not those"),
    (lambda s: s["log"].pop(1), "its log row 1 is not row 1"),
])
def test_a_state_whose_log_and_optimiser_disagree_is_refused(simulator, problem, tmp_path, edit, message):
    run = dict(level=1, loss="prt_cd", training=problem[0], validation_set=problem[0], iterations=2,
               initial=HAND_PICKED, simulator=simulator, progress=io.StringIO())
    identify(tmp_path, **run)
    _edit_state(tmp_path, edit)
    with pytest.raises(IdentificationError, match=f"{STATE_FILE} cannot be resumed: {message}.*Delete it to restart"):
        identify(tmp_path, **run)
    notes = io.StringIO()  # the workflow's mode: discarded, with a note
    identify(tmp_path, **{**run, "progress": notes}, restart_if_different=True)
    assert "starting afresh" in notes.getvalue() and "cannot be resumed" in notes.getvalue()


OUT_OF_RANGE = Parameters(E=1e6, nu=0.4, rho=1330.0, yield_stress=1e3, mu_table=0.7, mu_effector=0.7)


def test_the_best_iteration_is_chosen_by_the_validation_map_or_by_the_training_loss():
    def row(k, train_loss_mm, val_heightmap_mm):
        values = dict.fromkeys(COLUMNS, 0.0)
        return {**values, **HAND_PICKED.replace(E=1e4 * (k + 1)).as_dict(), "iteration": k,
                "train_loss_mm": train_loss_mm, "val_heightmap_mm": val_heightmap_mm}

    # row 0 (the initial values) fits best by both, but only updated rows are candidates
    rows = [row(0, 1.0, 1.0), row(1, 50.0, 700.0), row(2, 40.0, 800.0), row(3, math.nan, 600.0), row(4, 45.0, 900.0)]
    by_validation = identification.summarise(rows, {}, 4, TRUTH)
    by_training = identification.summarise(rows, {}, 4, TRUTH, select="training")
    assert (by_validation["best"]["iteration"], by_validation["selected_by"]) == (3, "validation")
    assert (by_training["best"]["iteration"], by_training["selected_by"]) == (2, "training")
    assert by_training["best"]["parameters"]["E"] == 3e4
    assert by_training["relative_error"]["E"] == pytest.approx(0.4)
    assert identification.summarise(rows[:1], {}, 0, TRUTH)["best"] is None  # never the initial values


@pytest.mark.parametrize("change, message", [
    ({"loss": "l2"}, "unknown loss 'l2'"),
    ({"training": []}, "training dataset is empty"),
    ({"validation_set": []}, "validation dataset is empty"),
    ({"level": 3}, "level must be one of"),
    ({"iterations": 0}, "iterations must be a positive integer"),
    ({"seed": -1}, "seed must be"),
    ({"initial": OUT_OF_RANGE}, "initial value: parameter E=1000000.0"),
    ({"known": {"mu_table": 1.0}}, "'mu_table'] are not identified at level 1"),
    ({"known": {"E": 5e4, "nu": 0.3, "rho": 1200.0, "yield_stress": 2500.0}}, "every parameter of level 1 is known"),
    ({"known": {"rho": 5000.0}}, "known value: parameter rho=5000.0"),
    ({"select": "final"}, "unknown choice of the best iteration 'final'"),
    ({"simulator": SimpleNamespace(config=SimulatorConfig(max_particles=100), forward=_failing)},
     "training datapoint 'round' has 245 particles, more than the simulator's max_particles=100"),
    ({"simulator": SimpleNamespace(config=dataclasses.replace(CONFIG, step_dt=0.005), forward=_failing)},
     "training datapoint 'round' has trajectory steps of 0.01 s, the simulator 0.005 s"),
])
def test_bad_arguments_fail_before_any_simulation(problem, tmp_path, change, message):
    untouchable = SimpleNamespace(config=CONFIG, forward=_failing, backward=_failing)
    args = {**dict(out_dir=tmp_path / "run", level=1, loss="prt_cd", training=problem[0],
                   validation_set=problem[1], simulator=untouchable), **change}
    with pytest.raises(IdentificationError, match=message.replace("(", r"\(")):
        identify(**args)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("change, message", [
    ({"start": np.array([0.0, 0.0, 0.06])}, "leaves the simulated box at step 0"),
    ({"particles": block() * [3.0, 1.0, 1.0]}, "particles lie outside the simulated box"),
])
def test_datapoint_outside_the_simulated_box_is_named_before_any_simulation(problem, tmp_path, change, message):
    """A lump too wide for the box, or a tip path leaving it: every simulation failed, and the run "stopped
    early" with exit 0 and no cause."""
    outside = dataclasses.replace(problem[0][1], **change)
    untouchable = SimpleNamespace(config=CONFIG, forward=_failing, backward=_failing)
    with pytest.raises(IdentificationError, match=f"training datapoint 'rectangle': .*{message}"):
        identify(tmp_path / "run", 1, "prt_cd", [problem[0][0], outside], problem[1], simulator=untouchable)
    assert not (tmp_path / "run").exists()


def test_oversized_earth_movers_target_is_named(problem, tmp_path):
    too_big = dataclasses.replace(problem[1][0], prt_target=np.zeros((300, 3)))
    with pytest.raises(IdentificationError, match="validation datapoint 'cylinder': prt_target has 300 points"):
        identify(tmp_path, 1, "prt_cd", problem[0], [too_big], simulator=SimpleNamespace(config=CONFIG))
