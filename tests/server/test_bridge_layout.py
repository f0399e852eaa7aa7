"""What a bridge must send and accept (m3p2i/bridge_layout.py, ``m3p2i layout``), checked
against the compiled models, and the planner stopping at a world whose first state has another
layout."""

from __future__ import annotations

import json
import threading
import time

import mujoco
import numpy as np
import pytest
import zmq
from typer.testing import CliRunner

from m3p2i.bridge_layout import bridge_layout, frame_names
from m3p2i.cli import app as m3p2i
from m3p2i.cli import free_port_block
from planner_client.model_state import StateSizes
from server.world import SimWorld
from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.frames import FrameResolver
from shared.robots import ROBOTS, get_robot
from shared.scenario import load_scenario
from shared.scene import STATE_FIELDS, compile_model


@pytest.fixture(scope="module")
def nav():
    sc = load_scenario("navigation")
    return sc, compile_model(sc)


@pytest.fixture(scope="module")
def panda():
    sc = load_scenario("pick_place")
    return sc, compile_model(sc)


def _covers(rows, size):
    assert [r.index for r in rows] == list(range(size))


def _ctrl_matches_model(layout, scenario, model):
    robot = scenario.robot.spec
    assert [c.actuator for c in layout.ctrl] == [model.actuator(a).name for a in range(model.nu)]
    assert [c.actuator for c in layout.ctrl] == list(robot.ctrl_names)
    np.testing.assert_array_equal([c.range for c in layout.ctrl], model.actuator_ctrlrange)
    np.testing.assert_array_equal([c.safe for c in layout.ctrl], robot.safe_stop())
    assert [c.unit for c in layout.ctrl] == list(robot.ctrl_units)


def test_navigation_layout_names_the_slides_the_velocity_actuators_and_the_fixed_objects(nav):
    sc, model = nav
    layout = bridge_layout(sc, model)
    assert layout.sizes == StateSizes(nq=model.nq, nv=model.nv, na=model.na, nmocap=model.nmocap)
    _covers(layout.qpos, model.nq)
    _covers(layout.qvel, model.nv)
    for rows, unit, component in ((layout.qpos, "m", "position"), (layout.qvel, "m/s", "velocity")):
        assert [(r.joint, r.joint_type, r.body, r.component, r.unit) for r in rows] == [
            ("x", "slide", "robot", component, unit),
            ("y", "slide", "robot", component, unit),
        ]
    assert [r.axis for r in layout.qpos] == [tuple(model.jnt_axis[j]) for j in range(2)]
    assert layout.act == ()
    fixed = [o.name for o in sc.world.objects if o.fixed]
    assert sorted(m.body for m in layout.mocap) == sorted(fixed)
    for slot in layout.mocap:
        assert slot.index == model.body_mocapid[model.body(slot.body).id] and slot.scenario_object
    _ctrl_matches_model(layout, sc, model)
    assert [(c.target, c.unit, c.holds_last) for c in layout.ctrl] == [
        ("joint x", "m/s", False),
        ("joint y", "m/s", False),
    ]
    assert layout.extras == ()
    assert layout.dt == sc.world.timestep and layout.scenario_hash == sc.hash


def test_pick_place_layout_names_the_panda_hinges_the_cubes_free_joints_and_the_gripper(panda):
    sc, model = panda
    layout = bridge_layout(sc, model)
    _covers(layout.qpos, model.nq)
    _covers(layout.qvel, model.nv)
    for r in layout.qpos:  # each row is where MuJoCo keeps that joint's coordinates
        j = model.joint(r.joint).id
        assert (
            model.jnt_qposadr[j]
            <= r.index
            < model.jnt_qposadr[j] + {"free": 7, "slide": 1, "hinge": 1}[r.joint_type]
        )
    hinges = layout.qpos[:7]
    assert [r.joint for r in hinges] == [f"panda_joint{i}" for i in range(1, 8)]
    assert {(r.joint_type, r.unit, r.component) for r in hinges} == {("hinge", "rad", "angle")}
    for r in hinges + layout.qpos[7:9]:
        np.testing.assert_array_equal(r.range, model.jnt_range[model.joint(r.joint).id])
    assert {(r.joint_type, r.unit) for r in layout.qpos[7:9]} == {("slide", "m")}
    for cube in ("cube_a", "cube_b"):
        j = model.joint(f"{cube}_free").id
        pos = [r for r in layout.qpos if r.joint == f"{cube}_free"]
        assert [r.index for r in pos] == list(range(model.jnt_qposadr[j], model.jnt_qposadr[j] + 7))
        assert [(r.component, r.unit, r.frame) for r in pos] == [
            (c, "m", "world") for c in "xyz"
        ] + [(c, "quaternion", "world") for c in ("qw", "qx", "qy", "qz")]
        assert {r.body for r in pos} == {cube}
        vel = [r for r in layout.qvel if r.joint == f"{cube}_free"]
        assert [r.index for r in vel] == list(range(model.jnt_dofadr[j], model.jnt_dofadr[j] + 6))
        assert [(r.component, r.unit, r.frame) for r in vel] == [
            (c, "m/s", "world") for c in ("vx", "vy", "vz")
        ] + [(c, "rad/s", "body") for c in ("wx", "wy", "wz")]
    assert [m.body for m in layout.mocap] == ["table"]
    _ctrl_matches_model(layout, sc, model)
    gripper = layout.ctrl[-1]
    assert (gripper.actuator, gripper.target, gripper.unit, gripper.range, gripper.holds_last) == (
        "gripper",
        "tendon gripper_width",
        "m",
        (0.0, 0.08),
        True,
    )
    assert not any(c.holds_last for c in layout.ctrl[:-1])
    assert {c.unit for c in layout.ctrl[:-1]} == {"rad/s"}


def test_free_joint_velocity_frames_are_what_the_layout_says(panda):
    """Linear velocity in the world frame, angular in the body's: checked in MuJoCo itself, with
    the cube turned 90 degrees about z so that the two frames differ."""
    _, model = panda
    data = mujoco.MjData(model)
    j = model.joint("cube_a_free").id
    q, v = model.jnt_qposadr[j], model.jnt_dofadr[j]
    data.qpos[q + 3 : q + 7] = [np.sqrt(0.5), 0, 0, np.sqrt(0.5)]
    data.qvel[v : v + 6] = [1.0, 0, 0, 1.0, 0, 0]  # vx = 1, wx = 1
    mujoco.mj_forward(model, data)
    world = np.zeros(6)  # [angular, linear], world frame
    mujoco.mj_objectVelocity(
        model, data, mujoco.mjtObj.mjOBJ_BODY, model.body("cube_a").id, world, 0
    )
    np.testing.assert_allclose(world[:3], [0, 1, 0], atol=1e-12)  # body x is world y
    np.testing.assert_allclose(world[3:], [1, 0, 0], atol=1e-12)  # world x as sent


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_declared_control_units_agree_with_velocity_servos_on_joints(name):
    robot = get_robot(name)
    model = mujoco.MjModel.from_xml_path(str(robot.path))
    assert len(robot.ctrl_units) == model.nu
    checked = 0
    for a in range(model.nu):
        gain, bias = model.actuator_gainprm[a][0], model.actuator_biasprm[a][:3]
        if (
            model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
            and gain > 0
            and bias[1] == 0
            and bias[2] == -gain
        ):  # a velocity servo on a joint
            kind = model.jnt_type[model.actuator_trnid[a][0]]
            assert robot.ctrl_units[a] == (
                "m/s" if kind == mujoco.mjtJoint.mjJNT_SLIDE else "rad/s"
            ), model.actuator(a).name
            checked += 1
    assert checked


@pytest.mark.parametrize("name", ["navigation", "battery_recharge", "pick_place"])
def test_the_simulated_world_sends_exactly_the_layout(name):
    sc = load_scenario(name)
    world = SimWorld(sc)
    world.reset()
    layout = bridge_layout(sc, world.model)
    state = world.state()
    assert layout.sizes.mismatches({f: getattr(state, f) for f in STATE_FIELDS}) == []
    assert sorted(world.extras) == sorted(e.name for e in layout.extras)
    if sc.world.battery:
        assert layout.extras[0].unit == "%" and layout.extras[0].range == (0.0, 100.0)


def test_state_sizes_name_each_array_that_differs():
    sizes = StateSizes(nq=2, nv=2, na=0, nmocap=4)
    good = {
        "qpos": np.zeros(2),
        "qvel": np.zeros(2),
        "act": np.zeros(0),
        "mocap_pos": np.zeros((4, 3)),
        "mocap_quat": np.zeros((4, 4)),
    }
    assert sizes.mismatches(good) == []
    bad = dict(good, qpos=np.zeros(3), mocap_pos=np.zeros((3, 3)))
    assert sizes.mismatches(bad) == [
        "qpos has 3 values, the scenario's model has nq = 2",
        "mocap_pos has shape [3, 3], the scenario's model has nmocap = 4 (shape [4, 3])",
    ]


# ---------------------------------------------------------------- m3p2i layout


def test_layout_command_prints_tables_and_json():
    runner = CliRunner()
    shown = runner.invoke(m3p2i, ["layout", "pick_place"])
    assert shown.exit_code == 0, shown.output
    for text in (
        "state.qpos [23]",
        "cube_a_free",
        "quaternion",
        "command.ctrl [8]",
        "tendon gripper_width",
        "keeps its last command",
        "table",
    ):
        assert text in shown.output
    raw = runner.invoke(m3p2i, ["layout", "battery_recharge", "--json"])
    assert raw.exit_code == 0, raw.output
    data = json.loads(raw.output)
    assert data["sizes"] == {"nq": 2, "nv": 2, "na": 0, "nmocap": 5}
    assert [c["actuator"] for c in data["ctrl"]] == ["vel_x", "vel_y"]
    assert data["ctrl"][0]["range"] == [-1.5, 1.5] and data["extras"][0]["name"] == "battery"
    assert data["qvel"][1] == {
        "index": 1,
        "joint": "y",
        "joint_type": "slide",
        "body": "robot",
        "component": "velocity",
        "unit": "m/s",
        "frame": "axis",
        "axis": [0.0, 1.0, 0.0],
        "range": None,
    }


def test_layout_command_lists_the_frames_a_scenario_may_name():
    # the robot's sites and bodies too: a Panda scenario names site:grasp and panda_hand
    runner = CliRunner()
    shown = runner.invoke(m3p2i, ["layout", "pick_place"], env={"COLUMNS": "200"})
    assert shown.exit_code == 0, shown.output
    frames_part = shown.output[shown.output.index("frames:") :]
    for text in ("site:grasp", "site:finger_left", "panda_hand", "cube_a", "table"):
        assert text in frames_part, frames_part
    data = json.loads(runner.invoke(m3p2i, ["layout", "pick_place", "--json"]).output)
    by_name = {f["name"]: f for f in data["frames"]}
    assert by_name["robot"] == {
        "name": "robot",
        "kind": "site",
        "part": "robot",
        "same_as": "site:grasp",
    }
    assert by_name["site:finger_left"]["part"] == "robot"
    assert by_name["panda_hand"] == {
        "name": "panda_hand",
        "kind": "body",
        "part": "robot",
        "same_as": None,
    }
    assert by_name["cube_a"]["part"] == "object"


@pytest.mark.parametrize("name", ["navigation", "pick_place", "battery_recharge"])
def test_the_frames_listed_are_the_names_the_processes_resolve(name):
    sc = load_scenario(name)
    model = compile_model(sc)
    resolve = FrameResolver(model, sc.robot.spec.frame)
    listed = [f.name for f in frame_names(sc, model)]
    assert listed == resolve.names()
    parts = {f.name: f.part for f in frame_names(sc, model)}
    assert {parts[o.name] for o in sc.world.objects} == {"object"}
    if sc.world.arena:
        assert parts["wall_north"] == "arena"


def test_layout_command_refuses_an_unknown_scenario_like_the_others():
    result = CliRunner().invoke(m3p2i, ["layout", "no_such_scenario"])
    assert result.exit_code == 2
    assert result.output.startswith("error: no_such_scenario: no such scenario file or name")


# ---------------------------------------------------------------- the planner's check


class FakeWorld:
    """A world on loopback: answers ``hello`` with ``welcome`` and then publishes ``state`` every
    20 ms (whatever the commands), until :meth:`close` (or ``duration`` seconds: a test that
    forgets to close it cannot leave it running)."""

    def __init__(self, port: int, scenario, nu: int, state: P.State, duration: float = 300.0):
        self.endpoints, self.scenario, self.nu = Endpoints(port=port), scenario, nu
        self.state = state
        self.commands: list[P.Command] = []
        self.ctx = zmq.Context()
        self._stop = threading.Event()
        self._deadline = time.monotonic() + duration
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        rep, pub, pull = (socket(self.ctx, kind) for kind in (zmq.REP, zmq.PUB, zmq.PULL))
        rep.bind(self.endpoints.control)
        pub.bind(self.endpoints.state)
        pull.bind(self.endpoints.command)
        welcomed = False
        try:
            while not self._stop.is_set() and time.monotonic() < self._deadline:
                if rep.poll(20):
                    rep.recv()
                    rep.send(
                        P.encode(
                            P.Welcome(
                                scenario=self.scenario.name,
                                scenario_hash=self.scenario.hash,
                                mode="lockstep",
                                dt=self.scenario.world.timestep,
                                nu=self.nu,
                                session="fake",
                            )
                        )
                    )
                    welcomed = True
                if welcomed:
                    pub.send(P.encode(self.state))
                while pull.poll(0):
                    self.commands.append(P.decode(pull.recv(), expect="command"))
        finally:
            for s in (rep, pub, pull):
                s.close(0)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.ctx.term()


def _bounded(call, world: FakeWorld, until=lambda: True, timeout: float = 60.0):
    """``call()``'s result, run in a thread beside ``world`` and waited for at most ``timeout``
    seconds (then the test fails instead of hanging); ``world`` is closed once ``until()``."""
    done = {}
    thread = threading.Thread(target=lambda: done.update(result=call()), daemon=True)
    thread.start()
    thread.join(timeout)
    deadline = time.monotonic() + 5
    while not until() and time.monotonic() < deadline:
        time.sleep(0.02)
    world.close()
    assert not thread.is_alive(), f"no result within {timeout:.0f} s"
    return done["result"]


def _state(model, nq: int, nmocap: int) -> P.State:
    return P.State(
        session="fake",
        seq=0,
        time=0.0,
        qpos=np.zeros(nq),
        qvel=np.zeros(model.nv),
        act=np.zeros(0),
        mocap_pos=np.zeros((nmocap, 3)),
        mocap_quat=np.tile([1.0, 0, 0, 0], (nmocap, 1)),
    )


def test_planner_stops_with_exit_code_3_naming_each_size_a_bridge_got_wrong(nav):
    from planner_client.cli import app as planner

    sc, model = nav
    port = free_port_block()
    world = FakeWorld(port, sc, model.nu, _state(model, model.nq + 1, model.nmocap - 1))
    args = ["--scenario", "navigation", "--port", str(port), "--threads", "1"]
    result = _bounded(lambda: CliRunner().invoke(planner, args), world)
    output = result.output
    assert result.exit_code == 3, output
    assert (
        "error: the world's state does not fit the planner's model of navigation: qpos has "
        "3 values, the scenario's model has nq = 2; mocap_pos has shape [3, 3], the "
        "scenario's model has nmocap = 4 (shape [4, 3]); mocap_quat has shape [3, 4], the "
        "scenario's model has nmocap = 4 (shape [4, 4]). `m3p2i layout navigation` prints "
        "the layout a world must send"
    ) in output
    assert "qvel" not in output.split("error:")[-1]  # only what differs is named
    assert world.commands == []


def test_planner_plans_for_a_bridge_of_the_right_layout(nav):
    from planner_client.build import build_client

    sc, model = nav
    port = free_port_block()
    world = FakeWorld(port, sc, model.nu, _state(model, model.nq, model.nmocap))
    client = build_client(sc, Endpoints(port=port), threads=2, diagnostics=False)
    stats = _bounded(lambda: client.run(max_iterations=1), world, until=lambda: world.commands)
    client.close()
    assert stats.iterations == 1
    assert world.commands and world.commands[0].session == "fake"
    assert world.commands[0].ctrl.shape == (model.nu,)
