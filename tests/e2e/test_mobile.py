"""The mobile manipulator (shared/robots/mobile_panda.xml, docs/mobile.md): the Panda it carries
is panda.xml's, its base drives as its file says, and its scenario passes the checks and lays out
base and arm for a bridge (both processes' checks of every shipped scenario, this one included:
tests/cli/test_check.py). The episodes themselves are measured by ``m3p2i bench mobile``
(docs/mobile.md): one takes minutes of a core, too long for the suite."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from typer.testing import CliRunner

from m3p2i.bridge_layout import bridge_layout
from m3p2i.cli import app as m3p2i
from planner_client.aip import ActiveInferencePlanner
from shared.robots import get_robot
from shared.scenario import load_scenario
from shared.scene import compile_model, initial_data

ARM_BODIES = [f"panda_link{i}" for i in range(1, 8)] + [
    "panda_hand",
    "panda_leftfinger",
    "panda_rightfinger",
]
ARM_JOINTS = [f"panda_joint{i}" for i in range(1, 8)] + [
    "panda_finger_joint1",
    "panda_finger_joint2",
]
ARM_ACTUATORS = [f"j{i}" for i in range(1, 8)] + ["gripper"]


def _load(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(get_robot(name).path))


@pytest.mark.parametrize("robot", ["mobile_panda", "mobile_panda_diff"])
def test_the_arm_on_the_base_is_panda_xml_unchanged(robot):
    panda, mobile = _load("panda"), _load(robot)
    for name in ARM_BODIES:
        a, b = panda.body(name), mobile.body(name)
        for field in ("pos", "quat", "mass", "inertia", "ipos", "iquat"):
            np.testing.assert_allclose(getattr(a, field), getattr(b, field), err_msg=name)
        assert panda.body_gravcomp[a.id] == mobile.body_gravcomp[b.id]
        ga = [g for g in range(panda.ngeom) if panda.geom_bodyid[g] == a.id]
        gb = [g for g in range(mobile.ngeom) if mobile.geom_bodyid[g] == b.id]
        for field in ("geom_type", "geom_size", "geom_pos", "geom_quat", "geom_friction"):
            np.testing.assert_array_equal(getattr(panda, field)[ga], getattr(mobile, field)[gb])
    for name in ARM_JOINTS:
        a, b = panda.joint(name), mobile.joint(name)
        for field in ("range", "armature", "damping", "axis"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=name)
    for name in ARM_ACTUATORS:
        a, b = panda.actuator(name), mobile.actuator(name)
        for field in ("gainprm", "biasprm", "ctrlrange", "forcerange"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=name)
    np.testing.assert_array_equal(panda.eq_data, mobile.eq_data)
    assert panda.opt.timestep == mobile.opt.timestep
    # the arm stands on the base's top, as the Panda stands on its table
    assert mobile.body("panda_link0").pos[2] == pytest.approx(0.845)


def test_the_base_drives_at_its_commanded_world_velocity_and_the_arm_holds_its_pose():
    sc = load_scenario("mobile_pick_place")
    model = compile_model(sc)
    data = initial_data(sc, model)
    arm0 = data.qpos[3:10].copy()
    data.ctrl[:] = get_robot("mobile_panda").safe_ctrl
    data.ctrl[:3] = (0.5, -0.3, 0.4)  # base_vx, base_vy, base_wz
    for _ in range(100):  # 1 s
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qvel[:3], (0.5, -0.3, 0.4), atol=0.01)
    np.testing.assert_allclose(data.qpos[:3], (0.5, -0.3, 0.4), atol=0.03)
    np.testing.assert_allclose(data.qpos[3:10], arm0, atol=0.02)
    # the chassis floats over the floor: no wheel or floor contacts slow it
    chassis = model.body("chassis").id
    assert not any(model.geom_bodyid[c.geom[i]] == chassis for c in data.contact for i in (0, 1))


def test_the_differential_drive_base_drives_along_its_heading_and_never_sideways():
    """mobile_panda_diff: the base goes where it faces at the commanded forward speed while it
    turns at the commanded rate; the tyres' grip keeps its sideways speed near zero."""
    sc = load_scenario("mobile_pick_place_diff")
    model = compile_model(sc)
    data = initial_data(sc, model)
    data.ctrl[:] = get_robot("mobile_panda_diff").safe_ctrl
    data.ctrl[:2] = (0.5, 0.4)  # base_forward, base_wz
    sideways = []
    for _ in range(100):  # 1 s: 0.4 rad of turn on the way, clear of table A
        mujoco.mj_step(model, data)
        yaw = data.qpos[2]
        sideways.append(-np.sin(yaw) * data.qvel[0] + np.cos(yaw) * data.qvel[1])
    yaw = data.qpos[2]
    assert yaw == pytest.approx(0.4, abs=0.03)
    forward = np.cos(yaw) * data.qvel[0] + np.sin(yaw) * data.qvel[1]
    assert forward == pytest.approx(0.5, abs=0.01)
    assert np.max(np.abs(sideways)) < 0.01
    # an arc of radius 0.5 / 0.4 m: the chord from the start
    assert np.hypot(*data.qpos[:2]) == pytest.approx(2 * 1.25 * np.sin(0.2), abs=0.03)


@pytest.mark.parametrize(
    "observed, action",
    [
        ({"holding": "holding"}, "drive"),
        ({"holding": "holding", "arrived": "arrived"}, "turn"),
        ({"holding": "holding", "facing": "facing"}, "carry"),
        ({"holding": "holding", "facing": "facing", "over": "over"}, "move2place"),
    ],
)
def test_the_differential_drive_base_drives_then_turns_to_face_table_b(observed, action):
    d = _decide("mobile_pick_place_diff", **observed)
    assert (d.status, d.action) == ("running", action)


def test_layout_lists_the_base_and_the_arm():
    sc = load_scenario("mobile_pick_place")
    layout = bridge_layout(sc, compile_model(sc))
    joints = [r.joint for r in layout.qpos]
    assert joints[:10] == ["base_x", "base_y", "base_yaw"] + ARM_JOINTS[:7]
    ctrl = [(c.actuator, c.unit) for c in layout.ctrl]
    assert ctrl[:3] == [("base_vx", "m/s"), ("base_vy", "m/s"), ("base_wz", "rad/s")]
    assert ctrl[3:] == [(f"j{i}", "rad/s") for i in range(1, 8)] + [("gripper", "m")]
    result = CliRunner().invoke(m3p2i, ["layout", "mobile_pick_place"])
    assert result.exit_code == 0, result.output
    for name in ("base_x", "base_yaw", "panda_joint7", "base_vx", "base_wz", "gripper"):
        assert name in result.output


def test_mobile_reactive_is_mobile_pick_place_with_its_disturbances():
    """mobile_reactive (docs/mobile.md): the base scenario's world and success test, a person
    walking back and forth across the aisle, the cube moved before the grasp and taken from the
    hand during the carry, and the robot kept off the person in every planned objective."""
    base, s = load_scenario("mobile_pick_place"), load_scenario("mobile_reactive")
    assert s.episode.success == base.episode.success
    assert s.world.randomize == base.world.randomize
    assert {o.name for o in base.world.objects} < {o.name for o in s.world.objects}
    path, moved, stolen = s.world.disturbances
    assert (path.object, path.loop) == ("person", True)
    # one leg along the aisle's middle, through the base's line (x 0.4-1.2) in -x: it meets the
    # base head-on, never from behind
    legs = list(zip(path.waypoints, path.waypoints[1:] + path.waypoints[:1]))
    aisle = [(a, b) for a, b in legs if round(a[1], 3) == round(b[1], 3) == 1.5]
    assert len(aisle) == 1 and aisle[0][0][0] > 1.2 and aisle[0][1][0] < 0.4
    assert moved.object == stolen.object == "cube_a"
    assert moved.when.b == "cube_a" and stolen.when.b == "cube_b"
    assert stolen.pos[1] < 0.4  # back on table A (y within its ±0.4 m)
    assert "person" in s.metrics.collisions.with_
    for action, objective in s.action_objectives.items():
        terms = s.objectives[objective].terms
        person = [t.params for t in terms if t.term == "collision" and t.params["a"] == "chassis"]
        assert {"a": "chassis", "obstacles": ["person"], "margin": 0.3} in person, action
        assert len(terms) > len(base.objectives[action].terms)


def _decide(name: str, **observed):
    """The action mobile_* scenario ``name``'s active inference picks from the start's states
    (nothing reached, held or placed) with ``observed`` overriding some."""
    sc = load_scenario(name)
    start = {f.name: f.states[1] for f in sc.task.factors}
    return ActiveInferencePlanner(sc.task).step({**start, **observed})


@pytest.mark.parametrize(
    "observed, action",
    [
        ({}, "reach"),
        ({"reachable": "reachable"}, "pick"),
        ({"holding": "holding"}, "carry"),
        ({"holding": "holding", "over": "over"}, "move2place"),
        ({"holding": "holding", "over": "over", "preplace": "at_preplace"}, "place"),
        ({"over": "over"}, "reach"),  # a cube dropped over cube B: fetched again
    ],
)
def test_mobile_pick_place_carries_over_cube_b_before_putting_it_down(observed, action):
    d = _decide("mobile_pick_place", **observed)
    assert (d.status, d.action) == ("running", action)


def test_mobile_pick_place_carries_with_the_arm_near_its_ready_pose_and_lowers_with_it_free():
    """docs/mobile.md: carry holds the arm near the ready pose (posture weight 1.0) and the cube
    at a walking pace; move2place's posture weighs 0.2 (at 1.0 the cube hung 2 cm short in real
    time). Every objective keeps the chassis 10 cm off both tables."""
    sc = load_scenario("mobile_pick_place")

    def weight(objective: str, term: str, **params) -> list[float]:
        return [
            t.weight
            for t in sc.objectives[objective].terms
            if t.term == term and all(t.params.get(k) == v for k, v in params.items())
        ]

    assert weight("carry", "posture", joints=None) == [1.0]
    assert weight("move2place", "posture", joints=None) == [0.2]
    assert weight("carry", "velocity", a="cube_a") == [0.5]
    assert weight("move2place", "velocity", a="cube_a") == []
    for objective in sc.action_objectives.values():
        keep_out = weight(objective, "collision", a="chassis", margin=0.1)
        assert keep_out == [20.0], objective


@pytest.mark.parametrize(
    "observed, action",
    [
        ({"reachable": "reachable"}, "pick"),
        ({"holding": "holding"}, "carry"),  # never into the compartment from the side
        ({"holding": "holding", "front": "in_front"}, "move2place"),
        ({"holding": "holding", "front": "in_front", "preplace": "at_preplace"}, "place"),
        ({"front": "in_front"}, "reach_top"),  # a cube dropped in line: fetched again
    ],
)
def test_mobile_shelf_template_carries_in_line_with_the_slot_before_going_in(observed, action):
    d = _decide("mobile_shelf", **observed)
    assert (d.status, d.action) == ("running", action)


def test_mobile_shelf_fuses_both_grasps_and_keeps_the_base_off_table_and_shelf():
    """mobile_shelf (docs/mobile.md): pick_shelf's two reach modes as alternatives, a slot drawn
    per seed that never collides, and the chassis kept 10 cm off the table and the shelf in every
    objective the plan uses; the collision metric counts the chassis against every board."""
    sc = load_scenario("mobile_shelf")
    assert _decide("mobile_shelf").alternatives == ("reach_top", "reach_side")
    slot = next(o for o in sc.world.objects if o.name == "slot")
    assert slot.visual
    assert "slot" in {r.object for r in sc.world.randomize}
    shelf = {o.name for o in sc.world.objects if o.name.startswith("shelf")}
    assert len(shelf) == 5 and set(sc.metrics.collisions.a) == {"chassis"}
    assert shelf | {"table_a"} == set(sc.metrics.collisions.with_)
    for action, objective in sc.action_objectives.items():
        keep_out = [
            (t.params["obstacles"], t.params["margin"], t.weight)
            for t in sc.objectives[objective].terms
            if t.term == "collision" and t.params["a"] == "chassis"
        ]
        assert keep_out == [(["table_a", "shelf"], 0.1, 20.0)], action
