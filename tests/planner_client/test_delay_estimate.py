"""Delays estimated online (planner.delays.measure, `m3p2i run --measure-delays`;
docs/faults.md): the actuation delay from how the robot answers the controls sent, the state
delay from the lag a world reports, in lock-step too."""

from __future__ import annotations

import numpy as np
import pytest

from planner_client.delay_estimate import ActuationDelayEstimate
from server.faults import FaultyWorld
from server.plan_player import PlanPlayer
from server.world import SimWorld
from shared.scenario import load_scenario
from shared.scenario.faults import FaultConfig
from shared.scene import compile_model
from shared.timed_plan import TimedPlan


def _drive(scenario: str, actuation_ms: float, speed: float, states: int = 60):
    """The scenario's world behind ``actuation_ms`` of actuation delay, played a new random
    plan every state (as a planner answering each one), and an estimate fed each state."""
    sc = load_scenario(scenario)
    world = FaultyWorld(SimWorld(sc, 0), FaultConfig(actuation_delay_ms=actuation_ms))
    model = compile_model(sc)
    dt = world.dt
    estimate = ActuationDelayEstimate(model, dt, max_steps=8)
    rng = np.random.default_rng(5)
    lo, hi = model.actuator_ctrlrange.T
    player, plans = PlanPlayer(), []
    for k in range(states):
        state = world.state()
        data = _mirror(model, state)
        estimate.observe(data, plans, world.safe_command())
        ctrl = np.clip(rng.uniform(-speed, speed, (4, model.nu)), lo, hi)
        plans.append(TimedPlan(state.time, dt, ctrl, k))
        player.receive(plans[-1])
        world.step(player.control(world.time)[0])
    return estimate


def _mirror(model, state):
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.time = state.qpos, state.qvel, state.time
    return data


@pytest.mark.parametrize(
    "scenario, actuation_ms, steps",
    [
        ("navigation", 150.0, 3),  # world steps of 50 ms
        ("navigation", 0.0, 0),
        ("pick_place", 25.0, 3),  # 10 ms: the lab profile's 25 ms, rounded up as the world does
    ],
)
def test_the_actuation_delay_is_found_from_the_robots_response(scenario, actuation_ms, steps):
    estimate = _drive(scenario, actuation_ms, speed=1.0)
    assert estimate.steps() == steps, estimate.errors


def test_a_robot_that_does_not_move_tells_nothing():
    estimate = _drive("navigation", 150.0, speed=0.0)
    assert estimate.steps() is None


def test_no_answer_before_enough_states():
    estimate = _drive("navigation", 150.0, speed=1.0, states=10)
    assert estimate.observed < estimate.min_states and estimate.steps() is None


def test_delays_estimate_is_read_checked_and_switched_on_by_the_command_line(tmp_path):
    import yaml

    from m3p2i.launch import EpisodeLaunch
    from planner_client.cli import with_delays
    from shared.config import ConfigError
    from shared.config_files import shipped

    raw = yaml.safe_load((shipped("scenarios") / "navigation.yaml").read_text())
    raw["planner"]["delays"] = {"measure": "yes"}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match=r"bad.yaml: planner.delays.measure.*true or false"):
        load_scenario(str(bad))
    sc = with_delays(load_scenario("navigation"), None, None, measure=True)
    assert sc.planner.delays.measure and sc.planner.delays.active
    cmds = EpisodeLaunch(scenario="n.yaml", run_dir=tmp_path, measure_delays=True).commands(5000)
    assert "--measure-delays" in cmds["planner"] and "--measure-delays" not in cmds["server"]


@pytest.mark.slow
def test_estimated_delays_do_what_declared_ones_do(tmp_path):
    """Navigation behind 200 ms of actuation and 100 ms of state delay, lock-step: a planner
    that measures the delays arrives about as soon as one told them (measured 3.35 s against
    3.25 s; 7.95 s unaware), and says what it found."""
    from m3p2i.launch import EpisodeLaunch, run_episode
    from shared.config_files import shipped

    faults = tmp_path / "delays.yaml"
    faults.write_text("actuation_delay_ms: 200\nstate_delay_ms: 100\n")
    run = run_episode(
        EpisodeLaunch(
            scenario=str(shipped("scenarios") / "navigation.yaml"),
            run_dir=tmp_path / "estimated",
            faults=str(faults),
            measure_delays=True,
            timeout=300,
        )
    )
    assert run.summary is not None and run.summary["status"] == "success", run.reason
    assert run.summary["time"] < 0.7 * 7.95
    log = (tmp_path / "estimated" / "planner.log").read_text()
    assert "actuation delay estimated at 4 world steps (200 ms)" in log
    assert "state delay measured at 2 world steps (100 ms)" in log  # state.lag, lock-step


def test_the_scored_prediction_starts_from_the_whole_state_welds_and_mocap_included():
    # the weld of a carried cube (eq_active) and the fixed objects' poses (mocap) are state too:
    # without them the candidates were scored on a world with the cube unwelded, the table home
    import mujoco

    from planner_client.problem import build_problem

    sc = load_scenario("pick_place")
    model = build_problem(sc).model
    assert model.neq and model.nmocap
    estimate = ActuationDelayEstimate(model, model.opt.timestep, max_steps=2)
    data = mujoco.MjData(model)
    data.eq_active[:] = 1
    data.mocap_pos[:] += 0.25
    mujoco.mj_forward(model, data)
    seen = []
    import planner_client.delay_estimate as D

    def spy(m, d, *args, **kwargs):
        seen.append((d.eq_active.copy(), d.mocap_pos.copy()))

    estimate.observe(data, [], np.zeros(model.nu))
    data.time += model.opt.timestep
    orig, D.predict = D.predict, spy
    try:
        estimate.observe(data, [], np.zeros(model.nu))
    finally:
        D.predict = orig
    assert len(seen) == 3
    for eq_active, mocap_pos in seen:
        assert eq_active.all()
        np.testing.assert_array_equal(mocap_pos, data.mocap_pos)


def test_a_planner_slower_than_three_world_steps_is_still_scored(caplog):
    # states 5 world steps apart (a planner that slow sees no state between): the gate was
    # 1..3 steps, so the estimate never answered and said nothing
    import mujoco

    sc = load_scenario("navigation")
    model = compile_model(sc)
    dt = model.opt.timestep
    estimate = ActuationDelayEstimate(model, dt, max_steps=8)
    data = mujoco.MjData(model)
    for k in range(3):
        data.time = 5 * k * dt
        estimate.observe(data, [], np.zeros(model.nu))
    assert estimate.observed == 2
    data.time += 100 * dt  # a gap longer than any candidate: not scored, said
    with caplog.at_level("WARNING", logger="m3p2i.planner"):
        estimate.observe(data, [], np.zeros(model.nu))
    assert estimate.observed == 2
    assert "not scored" in caplog.text
