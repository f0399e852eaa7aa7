"""Delay compensation (planner.delays, `m3p2i run --compensate`; docs/faults.md): the planner
plans from the state its plan will meet, past delays no message shows."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import yaml

from planner_client.timing import predict
from server.faults import FaultyWorld
from server.plan_player import PlanPlayer
from server.world import SimWorld
from shared.config import ConfigError
from shared.scenario import DelayConfig, load_scenario
from shared.scenario.faults import FaultConfig
from shared.scene import compile_model
from shared.timed_plan import TimedPlan

ACTUATION_MS, STATE_MS = 60.0, 30.0  # 6 and 3 steps of the Panda's 0.01 s
TOLERANCE = 1e-6  # rad or m: the same model stepped the same way


def _plans(nu: int) -> list[TimedPlan]:
    """A plan every 5 steps, each 8 knots long (so none runs out): joint speeds up to 0.4 rad/s,
    the hand kept open."""
    rng = np.random.default_rng(3)
    plans = []
    for k in range(20):
        ctrl = np.zeros((8, nu))
        ctrl[:, :7] = rng.uniform(-0.4, 0.4, (8, 7))
        ctrl[:, 7] = 0.08
        plans.append(TimedPlan(0.05 * k, 0.01, ctrl, k))
    return plans


def _run_until(world: FaultyWorld, player: PlanPlayer, t: float) -> None:
    """What the server does each step: the plan's control for the world's time, delayed by
    the faulty world."""
    while world.time < t - 1e-9:
        ctrl = player.control(world.time)[0]
        world.step(world.safe_command() if ctrl is None else ctrl)


def _mirror(model: mujoco.MjModel, state) -> mujoco.MjData:
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.time = state.qpos, state.qvel, state.time
    if model.na:
        data.act[:] = state.act
    return data


def test_the_compensated_prediction_is_the_worlds_state_when_the_plan_acts():
    """A world whose states are 30 ms old and whose actuators act 60 ms late: from the state
    it publishes at 0.30 s (measured at 0.27 s), the prediction over both delays under the plans
    sent, each acting 60 ms after the world plays it, is the true state at 0.36 s; planning
    from the received state as if it were now is off by centimetres."""
    sc = load_scenario("pick_place")
    world = FaultyWorld(
        SimWorld(sc, 0), FaultConfig(actuation_delay_ms=ACTUATION_MS, state_delay_ms=STATE_MS)
    )
    model = compile_model(sc)
    dt = model.opt.timestep
    plans = _plans(model.nu)
    player = PlanPlayer()
    for plan in plans:
        player.receive(plan)
    _run_until(world, player, 0.30)
    received = world.state()
    assert received.time == pytest.approx(0.27)
    data = _mirror(model, received)
    predict(model, data, plans, world.safe_command(), dt, steps=3 + 6, actuation_delay=6 * dt)
    _run_until(world, player, 0.36)
    truth = world.true_state()
    assert math.isclose(data.time, truth.time, abs_tol=1e-9)
    np.testing.assert_allclose(data.qpos, truth.qpos, atol=TOLERANCE)
    np.testing.assert_allclose(data.qvel, truth.qvel, atol=1e-4)
    # without compensation the plan would start from the received state
    stale = np.abs(received.qpos[:7] - truth.qpos[:7]).max()
    assert stale > 1000 * TOLERANCE
    # nor does predicting the time alone do: the actuators are still working off older plans
    undelayed = _mirror(model, received)
    predict(model, undelayed, plans, world.safe_command(), dt, steps=9)
    assert np.abs(undelayed.qpos[:7] - truth.qpos[:7]).max() > 100 * TOLERANCE


def test_delays_are_read_and_checked_with_file_key_and_expectation(tmp_path):
    from shared.config_files import shipped

    raw = yaml.safe_load((shipped("scenarios") / "navigation.yaml").read_text())
    raw["planner"]["delays"] = {"actuation_ms": 40, "state_ms": 25.5}
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(raw))
    assert load_scenario(str(good)).planner.delays == DelayConfig(40.0, 25.5)
    assert load_scenario("navigation").planner.delays == DelayConfig()
    assert not DelayConfig().active and DelayConfig(state_ms=1).active
    for delays, key in [
        ({"actuation_ms": -5}, "planner.delays.actuation_ms"),
        ({"actuation": 5}, "planner.delays.actuation"),
    ]:
        raw["planner"]["delays"] = delays
        bad = tmp_path / "bad.yaml"
        bad.write_text(yaml.safe_dump(raw))
        with pytest.raises(ConfigError) as err:
            load_scenario(str(bad))
        assert key in str(err.value) and "bad.yaml" in str(err.value)


def test_compensate_declares_the_faults_delays_to_the_planner_only(tmp_path):
    from typer.testing import CliRunner

    from m3p2i.cli import app
    from m3p2i.launch import EpisodeLaunch

    launch = EpisodeLaunch(
        scenario="navigation.yaml", run_dir=tmp_path, faults="lab", delays=(25.0, 25.0)
    )
    cmds = launch.commands(5000)
    assert cmds["planner"][-4:] == ["--actuation-delay-ms", "25.0", "--state-delay-ms", "25.0"]
    assert "--actuation-delay-ms" not in cmds["server"]
    result = CliRunner().invoke(app, ["run", "navigation", "--compensate"])
    assert result.exit_code == 2 and "no delay to compensate" in result.output


def test_the_planner_command_line_overrides_the_scenarios_delays():
    from planner_client.cli import with_delays

    sc = with_delays(load_scenario("navigation"), 80.0, None)
    assert sc.planner.delays == DelayConfig(actuation_ms=80.0, state_ms=0.0)
    assert with_delays(sc, None, 10.0).planner.delays == DelayConfig(80.0, 10.0)


@pytest.mark.slow
def test_compensation_makes_up_most_of_what_a_300_ms_round_trip_costs(tmp_path):
    """Navigation (not a chaotic episode) behind 200 ms of actuation and 100 ms of state delay:
    it arrives either way, but the compensated planner does not overshoot and wait, which the
    uncompensated one does (lock-step: the same on every run of one machine; measured 3.25 s
    against 7.95 s, and 2.98 s without delays)."""
    from m3p2i.launch import EpisodeLaunch, run_episode
    from shared.config_files import shipped

    faults = tmp_path / "delays.yaml"
    faults.write_text("actuation_delay_ms: 200\nstate_delay_ms: 100\n")
    times = {}
    for delays in (None, (200.0, 100.0)):
        run = run_episode(
            EpisodeLaunch(
                scenario=str(shipped("scenarios") / "navigation.yaml"),
                run_dir=tmp_path / str(delays),
                faults=str(faults),
                delays=delays,
                timeout=300,
            )
        )
        assert run.summary is not None and run.summary["status"] == "success", run.reason
        times[delays] = run.summary["time"]
    assert times[(200.0, 100.0)] < 0.7 * times[None]


@pytest.mark.parametrize(
    "mode, dated, acts",
    [
        ("lockstep", 2, 2 + 3),  # state delay (2 steps) to the plan's date, actuation (3) beyond
        ("realtime", 4, 4 + 3),
    ],
)  # the lead (a 0.2 s lag) already holds the state delay
def test_the_plan_is_dated_when_it_reaches_the_world_and_planned_for_when_it_acts(
    mode, dated, acts
):
    from planner_client.build import build_motion_planner, build_parts
    from planner_client.controller import Controller
    from planner_client.task import FixedModes
    from shared import protocol as P

    nav = load_scenario("navigation")  # world steps of 0.05 s
    planner = build_motion_planner(nav, threads=2)
    controller = Controller(
        build_parts(planner, FixedModes(("navigate",))),
        delays=DelayConfig(actuation_ms=150.0, state_ms=100.0),
    )
    try:
        model = planner.problem.model
        controller.begin(mode, 0.05)  # real time: a lead estimate, from the lag observed
        state = P.State(
            session="s",
            seq=7,
            time=1.0,
            qpos=np.zeros(model.nq),
            qvel=np.zeros(model.nv),
            act=np.zeros(model.na),
            mocap_pos=np.zeros((model.nmocap, 3)),
            mocap_quat=np.tile([1.0, 0, 0, 0], (model.nmocap, 1)),
            lag=0.2,
        )
        x0 = controller.mirror.apply(state)
        start, _, _ = controller._plan_start(state, x0)
        assert start == pytest.approx(1.0 + 0.05 * dated)
        assert controller.mirror.data.time == pytest.approx(1.0 + 0.05 * acts)
    finally:
        controller.close()
