"""The rollouts compute only the sensors the planned modes read (planner_client.sensors.
SensorSwitch): every objective of the shipped scenarios costs the same samples the same, bit for
bit, with only its own sensors computed as with all of them; the planner switches the set with
its modes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from planner_client.build import build_controller
from planner_client.costs import RolloutBatch
from planner_client.model_state import get_full_state
from planner_client.motion import MotionPlanner
from planner_client.problem import build_problem, mppi_config
from planner_client.rollout import RolloutEngine
from planner_client.sensors import SensorRequest
from shared.scenario import load_scenario
from shared.scene import initial_data

# several objectives each, or norms fused over columns of other objectives' sensors (pick_place),
# distances and contact forces (mobile_pick_place), clearance, a guide
SCENARIOS = [
    "navigation",
    "push_pull",
    "pick_place",
    "mobile_pick_place",
    "battery_recharge_clear",
    "navigation_trap_guided",
]


def _ids(problem, requests) -> np.ndarray:
    return np.array(sorted({problem.model.sensor(r.name).id for r in requests}))


@pytest.mark.parametrize("name", SCENARIOS)
def test_each_objective_costs_the_same_with_only_its_sensors_computed(name):
    sc = load_scenario(name)
    problem = build_problem(sc)
    model = problem.model
    x0 = get_full_state(model, initial_data(sc, model))
    lo, hi = model.actuator_ctrlrange.T
    rng = np.random.default_rng(0)
    controls = lo + (hi - lo) * rng.random((16, sc.planner.horizon, model.nu))
    V = torch.from_numpy(controls)
    engine = RolloutEngine(model, nthread=2)
    try:
        every = torch.from_numpy(engine.run(x0, controls).copy())
        uncomputed = 0  # objectives whose rollouts left some sensor uncomputed
        for objective_name, objective in problem.objectives.items():
            read = _ids(problem, [problem.robot_pos, *objective.sensors()])
            engine.read_sensors(read)
            own = torch.from_numpy(engine.run(x0, controls).copy())
            engine.read_sensors(None)
            dt = float(model.opt.timestep)
            expected = objective(RolloutBatch(every, V, problem.columns, dt))
            got = objective(RolloutBatch(own, V, problem.columns, dt))
            assert torch.equal(got, expected), objective_name
            columns = [i for r in objective.sensors() for i in range(*_span(problem, r))]
            assert torch.equal(own[..., columns], every[..., columns])
            uncomputed += not torch.equal(own, every)
        # the sensors switched back: every one computed again
        assert torch.equal(torch.from_numpy(engine.run(x0, controls)), every)
    finally:
        engine.close()
    if name in ("pick_place", "mobile_pick_place"):
        assert uncomputed > 0  # some objective reads fewer than all sensors: not vacuous


def _span(problem, req) -> tuple[int, int]:
    span = problem.columns.spans[req]
    return span.start, span.stop


def test_the_planner_computes_the_sensors_of_its_modes_and_changes_them_with_the_modes():
    sc = load_scenario("pick_place")
    controller = build_controller(sc, 2)
    try:
        motion = controller.motion
        problem, model = motion.problem, motion.problem.model
        compiled = build_problem(sc).model
        clock = int(mujoco.mjtSensor.mjSENS_CLOCK)

        def computed() -> set[int]:
            return {i for i in range(model.nsensor) if model.sensor_type[i] != clock}

        for modes in (["reach"], ["place"], ["reach", "place"]):
            motion.set_modes(modes)
            read = set(_ids(problem, [problem.robot_pos, *motion_sensors(problem, modes)]))
            assert computed() == read, modes
            assert np.array_equal(model.sensor_type[list(read)], compiled.sensor_type[list(read)])
            assert len(read) < model.nsensor
    finally:
        controller.close()


def test_the_planner_computes_the_extra_sensors_of_its_problem():
    sc = load_scenario("pick_place")
    extra = SensorRequest("jointvel", "panda_joint2")  # no objective of pick_place reads it
    problem = build_problem(sc, extra_sensors=[extra])
    assert extra not in {r for o in problem.objectives.values() for r in o.sensors()}
    motion = MotionPlanner(problem, mppi_config(sc, problem.model), 40, ["reach"], nthread=1)
    try:
        sensor = problem.model.sensor(extra.name)
        assert sensor.type[0] == int(mujoco.mjtSensor.mjSENS_JOINTVEL)
    finally:
        motion.close()


def motion_sensors(problem, modes):
    return [r for m in modes for r in problem.objectives[m].sensors()]
