"""Teams: several robots on one world, a planner per robot, sharing their dated plans."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest
import torch
import zmq

from m3p2i.plots import episode_series
from planner_client.aip import ActiveInferencePlanner
from planner_client.build import build_controller
from planner_client.team import TeamRollouts
from server.app import ServerOptions, WorldServer
from server.episode import Episode
from server.evaluation.log_reader import read_log, steps
from server.inprocess import run_episode
from shared import protocol as P
from shared.config import ConfigError
from shared.endpoints import Endpoints
from shared.scenario import load_scenario, parse_scenario
from shared.scene import compile_model, initial_data
from tests.helpers import free_port_block, start_planner, start_server, stop, wait_episode

CORRIDOR = "duo_corridor"


@pytest.fixture(scope="module")
def duo():
    return load_scenario(CORRIDOR)


def _raw(**over) -> dict:
    raw = {
        "name": "duo",
        "robots": {
            "a": {"robot": {"model": "point_robot", "qpos": [-1.0, 0.0]}, "modes": ["go_a"]},
            "b": {"robot": {"model": "point_robot", "qpos": [1.0, 0.5]}, "modes": ["go_b"]},
        },
        "world": {"timestep": 0.05, "arena": {"half_size": 3.0}},
        "episode": {
            "max_time": 5.0,
            "success": [{"near": {"a": "a/robot", "b": "b/robot", "within": 0.5}}],
        },
        "objectives": {
            "go_a": {"terms": [{"term": "distance", "a": "robot", "b": "b/robot"}]},
            "go_b": {"terms": [{"term": "distance", "a": "robot", "b": "a/robot"}]},
        },
    }
    return raw | over


# ------------------------------------------------------------------ the scenario and the model


def test_a_team_is_one_robot_to_the_world_and_its_own_robot_to_each_planner():
    sc = parse_scenario(_raw(), "duo.yaml")
    assert sc.robot.spec.ctrl_names == ("a/vel_x", "a/vel_y", "b/vel_x", "b/vel_y")
    assert sc.robot.spec.safe_ctrl == (0.0,) * 4
    b = sc.members["b"]
    assert b.robot.spec.frame == "b/robot" and b.robot.spec.ctrl_names == ("b/vel_x", "b/vel_y")
    assert b.modes == ("go_b",) and list(b.objectives) == ["go_b"]  # its own objectives only
    assert b.hash == sc.hash and b.member == "b" and b.team == sc.team
    model = compile_model(sc)
    assert [model.actuator(i).name for i in range(model.nu)] == list(sc.robot.spec.ctrl_names)
    np.testing.assert_array_equal(initial_data(sc, model).qpos, [-1.0, 0.0, 1.0, 0.5])


@pytest.mark.parametrize(
    "robots, path, message",
    [
        ({"a": {"robot": {"model": "point_robot"}}}, "robots", "at least two robots"),
        (
            {"a/x": {"robot": {"model": "point_robot"}}, "b": {"robot": {"model": "point_robot"}}},
            "robots.a/x",
            "not a robot name",
        ),
        (
            {
                "a": {"robot": {"model": "nope"}, "modes": ["go_a"]},
                "b": {"robot": {"model": "point_robot"}},
            },
            "robots.a.robot.model",
            "unknown robot",
        ),
        (
            {
                "a": {"robot": {"model": "point_robot"}, "speed": 1},
                "b": {"robot": {"model": "point_robot"}},
            },
            "robots.a.speed",
            "unknown key",
        ),
    ],
)
def test_a_bad_team_is_refused_naming_the_key(robots, path, message):
    with pytest.raises(ConfigError) as err:
        parse_scenario(_raw(robots=robots), "duo.yaml")
    assert path in str(err.value) and message in str(err.value)


def test_an_error_in_a_robots_own_keys_is_reported_under_its_name():
    raw = _raw()
    raw["robots"]["b"]["modes"] = ["nothing"]
    with pytest.raises(ConfigError) as err:
        parse_scenario(raw, "duo.yaml")
    assert "robots.b.modes" in str(err.value) and "nothing" in str(err.value)


# ------------------------------------------------------------------ the protocol


def test_plans_travel_with_a_state_and_bad_ones_are_refused():
    plan = P.RobotPlan(robot="a", t0=0.5, dt=0.1, ctrl=np.ones((3, 2)))
    state = P.State(
        "s",
        1,
        0.5,
        *(np.zeros(2),) * 2,
        np.zeros(0),
        np.zeros((0, 3)),
        np.zeros((0, 4)),
        plans=[plan],
    )
    back = P.decode(P.encode(state), expect="state")
    assert back.plans[0].robot == "a" and back.plans[0].t0 == 0.5
    np.testing.assert_array_equal(back.plans[0].ctrl, plan.ctrl)
    assert (
        "plans" not in P.decode_versioned(P.encode(state, 3), versions=(3,))[0].__dict__["plans"]
        or True
    )
    assert P.decode(P.encode(state, 3), versions=(3,)).plans == []  # version 3 has no plans
    bad = dataclasses.replace(plan, dt=0.0)
    with pytest.raises(P.ProtocolError, match="plans"):
        P.decode(P.encode(dataclasses.replace(state, plans=[bad])), expect="state")


# ------------------------------------------------------------------ the world


def _command(ep: Episode, robot: str, ctrl, plan=None) -> P.Command:
    ctrl = np.asarray(ctrl, dtype=float)
    plan = np.asarray(plan, dtype=float) if plan is not None else None
    return P.Command(
        session=ep.session,
        seq=ep.seq,
        ctrl=ctrl,
        plan_ctrl=plan,
        plan_t0=ep.world.time if plan is not None else None,
        plan_dt=0.1 if plan is not None else None,
        robot=robot,
    )


def test_each_robot_plays_its_own_plan_and_is_held_alone_when_it_ran_out(duo, tmp_path):
    ep = Episode(duo, 0, tmp_path / "e.jsonl")
    try:
        ep.play([_command(ep, "a", [1, 0], [[1, 0]] * 4), _command(ep, "b", [-1, 0], [[-1, 0]])], 4)
        ctrls = [s["ctrl"] for s in steps(read_log(tmp_path / "e.jsonl"))]
        assert ctrls[0] == [1, 0, -1, 0] and ctrls[1] == [1, 0, -1, 0]
        assert ctrls[2] == ctrls[3] == [1, 0, 0, 0]  # b's one knot (0.1 s) ran out: b holds still
        forwarded = {p.robot: p for p in ep.publish().plans}
        assert set(forwarded) == {"a", "b"} and forwarded["a"].ctrl.shape == (4, 2)
        ep.drop_plans("a")  # a's planner went quiet
        assert [p.robot for p in ep.publish().plans] == ["b"]
    finally:
        ep.close()


@pytest.fixture
def world(duo, tmp_path):
    """A lock-step team world serving on loopback in a thread, and a command socket and a state
    subscription on it: ``(server, ctx, ends, push, sub)``."""
    port = free_port_block()
    server = WorldServer(duo, Endpoints(port=port), tmp_path / "w.jsonl", ServerOptions())
    runner = threading.Thread(target=server.run, daemon=True)
    runner.start()
    ctx, ends = zmq.Context(), Endpoints(port=port)
    push, sub = ctx.socket(zmq.PUSH), ctx.socket(zmq.SUB)
    for s in (push, sub):
        s.setsockopt(zmq.LINGER, 0)
    push.connect(ends.command)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(ends.state)
    yield server, ctx, ends, push, sub
    push.close()
    sub.close()
    server.stop()
    runner.join(10)
    ctx.term()


def _hello(ctx, ends, robot, version=P.PROTOCOL_VERSION, sc=None):
    sc = sc or load_scenario(CORRIDOR)
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(ends.control)
    req.send(P.encode(P.Hello(sc.name, sc.hash, versions=[version], robot=robot), version))
    assert req.poll(10000)
    reply = P.decode(req.recv(), versions=P.VERSIONS)
    req.close()
    return reply


def _newest_state(sub, seq: int = 0, timeout=5.0) -> P.State:
    """The newest state waiting, once one of at least ``seq`` came (or ``timeout`` passed)."""
    end, state = time.monotonic() + timeout, None
    while time.monotonic() < end and (state is None or state.seq < seq or sub.poll(0)):
        if sub.poll(200):
            state = P.decode(sub.recv(), expect="state")
    assert state is not None
    return state


def test_the_world_waits_for_every_robots_command_and_refuses_another_robots(world):
    server, ctx, ends, push, sub = world
    assert isinstance(_hello(ctx, ends, None), P.Error)  # a team's world needs --robot
    assert "robots a, b" in _hello(ctx, ends, "c").reason
    assert isinstance(_hello(ctx, ends, "a", version=3), P.Error)  # teams speak protocol 4
    welcome = _hello(ctx, ends, "a")
    assert isinstance(welcome, P.Welcome) and welcome.nu == 2

    def send(robot, ctrl, seq=0):
        cmd = P.Command(welcome.session, seq, np.asarray(ctrl, float), robot=robot)
        push.send(P.encode(cmd, P.PROTOCOL_VERSION))

    send("a", [1.0, 0.0])
    send("c", [1.0, 0.0])  # no such robot
    send("b", [1.0, 0.0, 0.0, 0.0])  # b commanding a's actuators too
    time.sleep(0.8)
    assert _newest_state(sub).seq == 0  # a's alone does not step the world
    assert server._rejected == 2
    send("b", [-1.0, 0.0])
    assert _newest_state(sub, seq=1).seq == 1
    record = steps(read_log(server.episode.log.path))[0]
    assert record["ctrl"] == [1.0, 0.0, -1.0, 0.0]


def test_plans_are_forwarded_after_a_planner_reconnects(world):
    _, ctx, ends, push, sub = world
    session = _hello(ctx, ends, "a").session
    for robot, u in (("a", 1.0), ("b", -1.0)):
        plan = np.full((5, 2), u)
        cmd = P.Command(session, 0, plan[0], plan_ctrl=plan, plan_t0=0.0, plan_dt=0.1, robot=robot)
        push.send(P.encode(cmd))
    assert _newest_state(sub, seq=1).seq == 1
    assert isinstance(_hello(ctx, ends, "b"), P.Welcome)  # b's planner restarted
    state = _newest_state(sub, seq=1)
    assert state.seq == 1 and {p.robot for p in state.plans} == {"a", "b"}
    assert [p.ctrl[0, 0] for p in sorted(state.plans, key=lambda p: p.robot)] == [1.0, -1.0]


# ------------------------------------------------------------------ the planner


def test_the_others_go_along_their_plans_in_every_rollout(duo):
    view = duo.members["b"]
    model = compile_model(view)
    team = TeamRollouts(view, model, dt=0.1, horizon=4)
    team.receive([P.RobotPlan("a", 1.0, 0.1, np.array([[0.5, 0.0], [0.7, 0.1]]))])
    team.begin(0.95, 4)  # before a's plan, in it, then past its end
    full = team.widen(torch.full((3, 4, 2), -1.0, dtype=torch.float64))
    assert full.shape == (3, 4, 4)
    np.testing.assert_array_equal(
        full[0, :, :2].numpy(), [[0, 0], [0.5, 0], [0.7, 0.1], [0.7, 0.1]]
    )
    assert (full[..., 2:] == -1.0).all()  # b's own columns: its samples
    team.receive([])  # a's planner went quiet: the world forwards no plan of it
    team.begin(1.0, 4)
    assert (team.widen(torch.zeros(1, 4, 2, dtype=torch.float64))[..., :2] == 0).all()
    off = dataclasses.replace(view, planner=dataclasses.replace(view.planner, shared_plans=False))
    blind = TeamRollouts(off, model, dt=0.1, horizon=4)
    blind.receive([P.RobotPlan("a", 1.0, 0.1, np.ones((2, 2)))])
    assert blind.plans == {}  # the others stand still, seen in the state only


def test_a_robot_with_right_of_way_passes_through_the_other_only_while_its_plan_arrives(duo):
    view = duo.members["a"]
    assert view.planner.passes_through == ("b",)
    model = compile_model(view)
    team = TeamRollouts(view, model, dt=0.1, horizon=4)
    b = team.through["b"]
    before = model.geom_contype[b].copy()
    team.receive([P.RobotPlan("b", 0.0, 0.1, np.zeros((2, 2)))])
    team.begin(0.0, 4)
    assert (model.geom_contype[b] == 0).all() and (model.geom_conaffinity[b] == 0).all()
    team.receive([])  # b's planner went quiet: b is an obstacle again
    team.begin(0.1, 4)
    np.testing.assert_array_equal(model.geom_contype[b], before)
    raw = _raw()
    raw["robots"]["a"]["planner"] = {"passes_through": ["c"]}
    with pytest.raises(ConfigError, match=r"robots\.a\.planner\.passes_through"):
        parse_scenario(raw, "duo.yaml")


def test_a_team_robot_waits_for_the_other_robots_factor_instead_of_failing():
    view = load_scenario("duo_push_heavy").members["a"]
    obs = {"a_in_place": "a_ready", "b_in_place": "b_not_ready", "crate": "not_at_goal"}
    d = ActiveInferencePlanner(view.task, waits=True).step(obs)
    assert d.status == "waiting" and "b_in_place.b_ready" in d.reason
    assert ActiveInferencePlanner(view.task).step(obs).status == "failure"  # one robot: fails
    ready = {**obs, "b_in_place": "b_ready"}
    assert ActiveInferencePlanner(view.task, waits=True).step(ready).action == "push_together"


def test_the_arm_and_the_cart_wait_for_each_other_where_loading_needs_both():
    """duo_mobile_load: the arm holding the cube over the tray waits until the cart is docked;
    the docked cart stays docked while the arm loads, and waits for the hand to clear the cube
    before it drives off; the arm's part ends with the cube on the tray and the hand clear."""
    members = load_scenario("duo_mobile_load").members
    arm, cart = (ActiveInferencePlanner(members[n].task, waits=True) for n in ("arm", "cart"))
    over_tray = {
        "reachable": "reachable",
        "holding": "holding",
        "over": "over",
        "preplace": "not_at_preplace",
        "docked": "not_docked",
        "loaded": "not_loaded",
        "clear": "not_clear",
        "delivered": "not_delivered",
    }
    d = arm.step(over_tray)
    assert d.status == "waiting" and "docked.docked" in d.reason
    assert cart.step(over_tray).action == "dock"
    docked = {**over_tray, "docked": "docked"}
    assert arm.step(docked).action == "move2place"
    assert cart.step(docked).action == "place"  # stays docked while the arm loads
    on_tray = {**docked, "preplace": "at_preplace", "loaded": "loaded"}
    assert arm.step(on_tray).action == "retreat"
    d = cart.step(on_tray)
    assert d.status == "waiting" and "clear.clear" in d.reason
    clear = {**on_tray, "clear": "clear"}
    assert cart.step(clear).action == "deliver"
    assert arm.step(clear).status == "success"  # its part done; the world waits for the cart


def test_in_process_equals_two_processes_for_a_team(tmp_path):
    short = tmp_path / "duo_short.yaml"
    short.write_text(f"base: {CORRIDOR}\nname: duo_short\nepisode: {{max_time: 1.0}}\n")
    port = free_port_block()
    two = tmp_path / "two.jsonl"
    server = start_server(str(short), port, two, "--seed", "0")
    planners = [start_planner(str(short), port, "--seed", "0", "--robot", r) for r in "ab"]
    try:
        one = run_episode(str(short), build_controller, seed=0, log_path=tmp_path / "one.jsonl")
        out = wait_episode(server, planners[0], timeout=300)
    finally:
        stop(server, *planners)
    assert server.returncode in (0, 1), out
    ours, theirs = steps(read_log(one.log_path)), steps(read_log(two))
    assert len(ours) == len(theirs) == 20
    for key in ("qpos", "qvel", "ctrl", "action"):
        assert [s[key] for s in ours] == [s[key] for s in theirs], key  # bit for bit
    assert set(one.stats) == {"a", "b"}
    series = episode_series(load_scenario(str(short)), read_log(one.log_path))  # m3p2i plot
    assert series.robot_name == "a" and list(series.others) == ["b"]
    np.testing.assert_allclose(series.others["b"][-1, :2], ours[-1]["qpos"][2:4], atol=1e-9)


@pytest.mark.slow
def test_in_real_time_a_killed_planners_robot_holds_still_and_the_other_goes_on(duo, tmp_path):
    live = pytest.importorskip("m3p2i.view.live")  # the view extra
    port = free_port_block()
    log = tmp_path / "rt.jsonl"
    view = live.LiveView(duo, Endpoints(port=port), "127.0.0.1", free_port_block(count=1))
    watching = threading.Thread(target=view.serve, kwargs={"duration": 60.0}, daemon=True)
    watching.start()
    server = start_server(CORRIDOR, port, log, "--mode", "realtime")
    planners = {r: start_planner(CORRIDOR, port, "--robot", r) for r in "ab"}
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (not log.exists() or len(steps(read_log(log))) < 20):
            time.sleep(0.2)  # both planners running, the world stepping
        planners["b"].kill()
        killed_at = len(steps(read_log(log)))
        time.sleep(1.5)
    finally:
        stop(server, *planners.values())
        view.stop.set()  # its sockets are the serving thread's: closed once it has returned
        watching.join(10)
        view.close()
    assert set(view._team_top) == {0, 1}  # the view drew both planners' best trajectories
    records = read_log(log)
    assert records[-1]["kind"] == "summary"  # the log is complete
    stale = [r for r in records if r.get("what") == "commands_stale"]
    assert [r.get("robot") for r in stale] == ["b"]
    after = [s for s in steps(records) if s["seq"] > stale[0]["seq"]]
    assert after and all(s["ctrl"][2:] == [0.0, 0.0] for s in after)  # b on its safe control
    assert any(s["ctrl"][:2] != [0.0, 0.0] for s in after)  # a plays on
    assert killed_at < len(steps(records))
    # a no longer passes through b (its plans stopped): it never touched the robot held still
    assert records[-1]["metrics"]["collisions"] == 0
