"""The planner's MuJoCo side: mirroring states, moving-obstacle prediction in rollouts, and
M3P2I over real rollouts lowering the navigation cost."""

import dataclasses
import logging

import mujoco
import numpy as np
import pytest
import torch

from planner_client.build import build_motion_planner, build_parts
from planner_client.controller import Controller
from planner_client.loop import PlannerClient
from planner_client.mirror import Mirror
from planner_client.problem import build_problem
from planner_client.rollout import RolloutEngine
from planner_client.sensors import SensorRequest
from planner_client.task import FixedModes
from shared import protocol as P
from shared.scenario import load_scenario


@pytest.fixture(scope="module")
def nav():
    return load_scenario("navigation")


def _state(model, time, qpos=None, mocap_pos=None):
    return P.State(
        session="s",
        seq=0,
        time=time,
        qpos=np.zeros(model.nq) if qpos is None else np.asarray(qpos, float),
        qvel=np.zeros(model.nv),
        act=np.zeros(model.na),
        mocap_pos=np.zeros((model.nmocap, 3)) if mocap_pos is None else mocap_pos,
        mocap_quat=np.tile([1.0, 0, 0, 0], (model.nmocap, 1)),
    )


def test_mirror_copies_state_and_estimates_mocap_velocity(nav):
    planner = build_motion_planner(nav, threads=2)
    model = planner.problem.model
    mirror = Mirror(model)
    base = mujoco.MjData(model).mocap_pos.copy()  # the fixed objects' poses
    mirror.apply(_state(model, 1.0, [0.5, -0.5], base.copy()))
    np.testing.assert_allclose(mirror.data.xpos[model.body("robot").id][:2], [0.5, -0.5])
    assert not mirror.mocap().moving
    moved = base.copy()
    moved[0] += [0.05, 0.0, 0.0]  # 0.05 m in 0.05 s: 1 m/s
    mirror.apply(_state(model, 1.05, [0.5, -0.5], moved))
    vel = mirror.mocap().vel
    np.testing.assert_allclose(vel[0], [1.0, 0, 0], atol=1e-9)
    assert not vel[1:].any()
    teleported = moved.copy()
    teleported[0] += [2.0, 0.0, 0.0]  # 40 m/s: a disturbance, not motion
    mirror.apply(_state(model, 1.10, [0.5, -0.5], teleported))
    assert not mirror.mocap().moving
    planner.close()


def test_mismatched_state_is_refused(nav):
    planner = build_motion_planner(nav, threads=2)
    mirror = Mirror(planner.problem.model)
    with pytest.raises(ValueError, match=r"state\.qpos has 3 values"):
        mirror.apply(_state(planner.problem.model, 0.0, [0.0, 0.0, 0.0]))
    planner.close()


def test_moving_obstacle_follows_the_constant_velocity_prediction_in_rollouts(nav):
    req = SensorRequest("framepos", "block_a")
    problem = build_problem(nav, [req])
    model = problem.model
    mirror = Mirror(model)
    x0 = mirror.apply(_state(model, 0.0, mocap_pos=mujoco.MjData(model).mocap_pos.copy()))
    pos = mirror.data.mocap_pos.copy()
    pos[int(model.body_mocapid[model.body("block_a").id])] += [1.0, 0.5, 0.0]  # moved by the world
    vel = np.zeros_like(pos)
    mocap = int(model.body_mocapid[model.body("block_a").id])
    vel[mocap] = [0.0, -1.0, 0.0]
    T, dt = 15, model.opt.timestep
    engine = RolloutEngine(model, 1)
    engine.set_mocap(pos, mirror.data.mocap_quat)
    controls = np.zeros((3, T, model.nu))
    sd = engine.run(x0, controls, pos[None] + vel[None] * (np.arange(T)[:, None, None] * dt))
    y = sd[:, :, problem.columns.spans[req]][..., 1]  # [S, T]
    np.testing.assert_allclose(y, np.tile(pos[mocap, 1] - np.arange(T) * dt, (3, 1)), atol=1e-9)
    sd = engine.run(x0, controls)  # no prediction: it stays
    np.testing.assert_allclose(sd[:, :, problem.columns.spans[req]][..., 1], pos[mocap, 1])
    engine.close()


def test_planner_iterations_lower_the_navigation_cost(nav):
    planner = build_motion_planner(nav, threads=2)
    model = planner.problem.model
    mirror = Mirror(model)
    x0 = mirror.apply(_state(model, 0.0))
    costs = [float(planner.iterate(x0).result.mode_costs[0]) for _ in range(15)]
    assert costs[-1] < 0.95 * costs[0]
    assert min(costs[5:]) <= min(costs[:5])
    planner.close()


def test_pinned_channels_follow_the_dominant_mode():
    import yaml

    from shared.scenario import SCENARIO_DIR, parse_scenario

    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["robot"] = {"model": "point_robot_suction", "qpos": [0.0, 0.0]}
    goal_terms = raw["objectives"]["navigate"]["terms"]
    far = [{"term": "distance", "a": "robot", "b": "block_b", "weight": 1000.0}]
    raw["objectives"] = {
        "push": {"terms": goal_terms, "fixed": {"suction": 0.0}},
        "pull": {"terms": goal_terms + far, "fixed": {"suction": 1.0}},
    }
    raw["modes"] = ["push", "pull"]
    planner = build_motion_planner(parse_scenario(raw, "hybrid.yaml"), threads=2)
    model = planner.problem.model
    x0 = Mirror(model).apply(_state(model, 0.0))
    for _ in range(3):
        plan = planner.iterate(x0)
    assert plan.dominant == "push"
    assert plan.result.mode_weights[0] > 0.99
    assert plan.command[2] == 0.0  # suction off, as push pins it
    planner.set_modes(["pull", "push"])
    assert planner.iterate(x0).command[2] == 0.0  # push still dominates
    planner.close()


def test_top_trajectories_are_each_modes_cheapest_samples_read_before_the_next_iteration(nav):
    planner = build_motion_planner(nav, threads=2)
    model = planner.problem.model
    x0 = Mirror(model).apply(_state(model, 0.0))
    it = planner.iterate(x0)
    costs, V = planner.mppi.costs.copy(), planner.last_samples.copy()
    top = it.top
    assert top.shape == (planner.top_k, nav.planner.horizon, 3)
    assert list(it.top_modes) == [0] * planner.top_k
    # the robot's positions along the five lowest-cost samples: rolled out again, the same
    cheapest = np.argsort(costs, kind="stable")[: planner.top_k]
    engine = RolloutEngine(model, 1)
    sd = torch.from_numpy(engine.run(x0, V[cheapest]).copy())
    np.testing.assert_array_equal(top, planner.problem.columns.take(sd, planner.problem.robot_pos))
    engine.close()
    assert it.top is top  # made once, kept
    unread = planner.iterate(x0)
    planner.iterate(x0)  # overwrites unread's rollouts
    with pytest.raises(RuntimeError, match="after the next iterate"):
        unread.top  # noqa: B018 - the property raises
    planner.close()


def test_diagnostics_are_made_only_while_someone_subscribes():
    import time
    import types

    import zmq

    ctx = zmq.Context()
    xpub = ctx.socket(zmq.XPUB)
    port = xpub.bind_to_random_port("tcp://127.0.0.1")
    client = types.SimpleNamespace(diag=xpub, _listeners=0, _field_listeners=0)
    listened = lambda: PlannerClient._listened(client)  # noqa: E731

    def until(want: bool) -> bool:
        for _ in range(200):  # 2 s at most
            if listened() == want:
                return True
            time.sleep(0.01)
        return False

    try:
        assert not listened()
        subs = [ctx.socket(zmq.SUB) for _ in range(2)]
        for sub in subs:
            sub.setsockopt(zmq.SUBSCRIBE, b"")
            sub.connect(f"tcp://127.0.0.1:{port}")
        assert until(True)
        subs[0].close(0)
        time.sleep(0.1)
        assert listened()  # one still listens
        subs[1].close(0)
        assert until(False)
    finally:
        xpub.close(0)
        ctx.term()


class _Faulty:
    """An objective that returns NaN everywhere while ``broken`` is set (a diverged model or a
    faulty cost term)."""

    def __init__(self, objective):
        self.objective, self.fixed, self.broken = objective, objective.fixed, False

    def __call__(self, batch):
        costs = self.objective(batch)
        return costs * np.nan if self.broken else costs


def test_no_finite_cost_sends_the_safe_control_and_says_why(nav, caplog):
    planner = build_motion_planner(nav, threads=2)
    faulty = _Faulty(planner.problem.objectives["navigate"])
    planner.problem.objectives["navigate"] = faulty
    controller = Controller(build_parts(planner, FixedModes(("navigate",))))
    controller.begin("lockstep", nav.world.timestep)
    safe = controller.robot.safe_stop()
    model = planner.problem.model
    plans = []
    try:

        def step(seq, broken):
            faulty.broken = broken
            state = dataclasses.replace(_state(model, 0.05 * seq), seq=seq)
            command = controller.step(state)
            plans.append(controller.last.iteration)
            return command.ctrl

        for seq in range(3):
            assert not np.array_equal(step(seq, False), safe)  # a plan is sent
        with caplog.at_level(logging.INFO, logger="m3p2i.planner"):
            for seq in range(3, 7):
                np.testing.assert_array_equal(step(seq, True), safe)
                assert plans[-1].fault is not None
                assert torch.isfinite(planner.mppi.nominal).all()
                assert torch.isfinite(planner.mppi.means).all()
            warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
            assert len(warnings) == 1, warnings  # once, not every iteration
            assert "no finite cost" in warnings[0].getMessage()
            assert "safe control" in warnings[0].getMessage()
            ctrl = step(7, False)  # planning resumes
        assert plans[-1].fault is None
        np.testing.assert_array_equal(ctrl, plans[-1].command)
        assert any("resumed" in r.getMessage() for r in caplog.records)
        assert controller.stats.safe_fallbacks == 4
    finally:
        controller.close()


def test_the_end_of_an_episode_is_logged_once_however_often_the_world_repeats_it(nav, caplog):
    planner = build_motion_planner(nav, threads=2)
    controller = Controller(build_parts(planner, FixedModes(("navigate",))))
    model = planner.problem.model
    end = dataclasses.replace(_state(model, 2.0), seq=40, status="success")
    try:
        with caplog.at_level(logging.INFO, logger="m3p2i.planner"):
            assert all(controller.over(end) for _ in range(3))  # re-published by a kept world
            assert controller.over(dataclasses.replace(end, session="next"))
        ends = [r.getMessage() for r in caplog.records if "episode over" in r.getMessage()]
        assert ends == ["episode over: success at t=2.00 s"] * 2
        assert controller.stats.final_status == "success"
    finally:
        controller.close()
