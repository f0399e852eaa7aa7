"""Cost terms on hand-made states with known values, and the YAML errors of objectives.

Most tests fill a :class:`RolloutBatch` directly (hand-written sensor columns), so
each expected number follows from the equation alone. The rest compile a small model with the
terms' sensors and set its state by hand, to pin what MuJoCo's sensors deliver to the terms.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from mujoco import rollout as mj_rollout

from planner_client.costs import TERMS, JointInfo, RolloutBatch, TermContext, build_objective
from planner_client.costs.base import Norm
from planner_client.costs.helpers import norm, sparse_norm
from planner_client.costs.norms import NormObjective, fusable
from planner_client.guide import GuideState
from planner_client.sensors import SensorColumns, SensorRequest, add_sensors
from planner_client.spheres import add_sphere_sites, robot_spheres
from shared.config import ConfigError, Section
from shared.frames import FrameResolver
from shared.scenario import ObjectiveConfig, TermConfig
from shared.scenario.guide import GuideConfig

F64 = torch.float64
SRC = "test.yaml"

# A robot "base" (slide x/y, motor forces ux/uy) with a bumper in front and a hand with two
# fingertip sites above, a fixed wall and pillar, a free box, a goal marker and a jointed obstacle
# moving on its own slide joint.
MJCF = """
<mujoco>
  <option timestep="0.01" gravity="0 0 0"/>
  <worldbody>
    <body name="base" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <geom name="base" type="sphere" size="0.1" mass="1"/>
      <body name="bumper" pos="0.15 0 0"><geom type="sphere" size="0.05" mass="0.1"/></body>
      <body name="hand" pos="0 0 0.3">
        <geom type="box" size="0.02 0.05 0.02" mass="0.1" contype="0" conaffinity="0"/>
        <site name="left" pos="0 0.03 0"/>
        <site name="right" pos="0 -0.03 0"/>
      </body>
    </body>
    <body name="wall" pos="1 0 0.1"><geom type="box" size="0.1 1 0.1"/></body>
    <body name="pillar" pos="-1 -1 0.1"><geom type="cylinder" size="0.1 0.1"/></body>
    <body name="box" pos="0 -0.5 0.1">
      <freejoint/><geom type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
    <body name="goal" pos="2 2 0">
      <geom type="sphere" size="0.05" contype="0" conaffinity="0"/>
    </body>
    <body name="mover" pos="-2 2 0.1">
      <joint name="mover_x" type="slide" axis="1 0 0"/>
      <geom type="sphere" size="0.1" mass="1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator><motor name="ux" joint="x"/><motor name="uy" joint="y"/></actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(MJCF)


@pytest.fixture(scope="module")
def ctx(model) -> TermContext:
    # the base's slide joints as the robot's: x unlimited, y given a range of ±0.5 m
    joints = {
        "x": JointInfo(range=None, hinge=False, start=0.0),
        "y": JointInfo(range=(-0.5, 0.5), hinge=False, start=0.1),
    }
    return TermContext(
        SRC,
        FrameResolver(model, "base"),
        obstacles=["wall", "pillar"],
        actuators=["ux", "uy"],
        joints=joints,
        # a guide for the box, with no path yet (the guide's terms:
        # tests/planner_client/test_guide.py)
        guide=GuideState(GuideConfig(for_="box", goal="goal", room="push"), scenario=None),
    )


def make(ctx: TermContext, name: str, **params):
    s = Section(params, SRC, "objectives.o.terms[0]")
    term = TERMS[name].from_params(s, ctx)
    s.done()
    return term


def batch_of(values: dict[SensorRequest, list], controls=None, dt: float = 0.1) -> RolloutBatch:
    """A batch from values ``[S, T, dim]`` per request (nested lists), controls ``[S, T, nu]``."""
    columns, blocks, start = {}, [], 0
    for req, v in values.items():
        t = torch.as_tensor(v, dtype=F64)
        columns[req] = slice(start, start + t.shape[-1])
        start += t.shape[-1]
        blocks.append(t)
    sensordata = torch.cat(blocks, dim=-1)
    if controls is None:
        controls = torch.zeros(*sensordata.shape[:2], 2, dtype=F64)
    return RolloutBatch(
        sensordata, torch.as_tensor(controls, dtype=F64), SensorColumns(columns), dt
    )


def test_a_terms_sensors_are_read_in_request_order_wherever_they_lie():
    a, b, c = pos("a"), SensorRequest("jointpos", "j"), SensorRequest("framezaxis", "c")
    columns = SensorColumns({a: slice(0, 3), b: slice(3, 4), c: slice(4, 7)})
    sd = torch.arange(2 * 7, dtype=F64).reshape(2, 1, 7)
    for _ in range(2):  # worked out once, then looked up
        apart = columns.take_all(sd, [c, a])
        torch.testing.assert_close(apart, torch.cat([sd[..., 4:7], sd[..., 0:3]], dim=-1))
        adjacent = columns.take_all(sd, [a, b])
        assert adjacent.data_ptr() == sd.data_ptr() and adjacent.shape == (2, 1, 4)


def pos(frame: str) -> SensorRequest:
    return SensorRequest("framepos", frame)


def one_step(*xs) -> list:
    """S samples of one step each: ``[S, 1, dim]`` from S vectors."""
    return [[list(x)] for x in xs]


def close(actual: torch.Tensor, expected) -> None:
    torch.testing.assert_close(actual, torch.as_tensor(expected, dtype=F64), rtol=1e-12, atol=1e-12)


def set_qpos(start: int, values):
    """A state setup for :func:`sensed`: ``qpos[start:]`` = values (box: qpos[2:9], free joint)."""

    def setup(d):
        d.qpos[start : start + len(values)] = values

    return setup


def sensed(model: mujoco.MjModel, ctx: TermContext, term, setup, steps: int = 0) -> RolloutBatch:
    """A one-step batch from the real sensors of ``term`` after ``setup(data)`` (and ``steps``)."""
    spec = mujoco.MjSpec.from_string(MJCF)
    add_sensors(spec, term.sensors(), ctx.resolve)
    m = spec.compile()
    d = mujoco.MjData(m)
    setup(d)
    for _ in range(steps):
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    sd = torch.as_tensor(d.sensordata.copy(), dtype=F64).reshape(1, 1, -1)
    ctrl = torch.as_tensor(d.ctrl.copy(), dtype=F64).reshape(1, 1, -1)
    return RolloutBatch(sd, ctrl, SensorColumns.of_model(m, term.sensors()), m.opt.timestep)


# --- distance, velocity (paper Eq. 14) ------------------------------------------------------------


def test_distance_in_3d_and_in_the_plane(ctx):
    b = batch_of(
        {pos("robot"): one_step((0, 0, 0), (1, 1, 1)), pos("goal"): one_step((3, 4, 12), (1, 1, 1))}
    )
    close(make(ctx, "distance", a="robot", b="goal")(b), [[13.0], [0.0]])
    close(make(ctx, "distance", a="robot", b="goal", axes="xy")(b), [[5.0], [0.0]])


def test_distance_along_two_axes_ignores_the_third(ctx):
    # a side grasp lines up level with the cube (xz) before it moves in along y
    b = batch_of(
        {pos("robot"): one_step((0, 0, 0), (1, 1, 1)), pos("goal"): one_step((3, 12, 4), (1, 7, 1))}
    )
    close(make(ctx, "distance", a="robot", b="goal", axes="xz")(b), [[5.0], [0.0]])
    close(make(ctx, "distance", a="robot", b="goal", axes="yz")(b), [[math.hypot(12, 4)], [6.0]])
    # one axis: a box held at its resting height, whatever it does in the plane (push_lab)
    close(make(ctx, "distance", a="robot", b="goal", axes="z")(b), [[4.0], [0.0]])
    close(make(ctx, "distance", a="robot", b="goal", axes="y")(b), [[12.0], [6.0]])


def test_distance_to_an_offset_target(ctx):
    # the paper's pre-place location: a point above a movable object
    b = batch_of(
        {
            pos("robot"): one_step((1, 2, 3.05), (1, 2, 3)),
            pos("goal"): one_step((1, 2, 3), (1, 2, 3)),
        }
    )
    close(make(ctx, "distance", a="robot", b="goal", offset=[0, 0, 0.05])(b), [[0.0], [0.05]])
    close(
        make(ctx, "distance", a="robot", b="goal", offset=[3, 4, 0], axes="xy")(b), [[5.0], [5.0]]
    )


def test_distance_reads_the_real_frame_positions(model, ctx):
    term = make(ctx, "distance", a="robot", b="goal")
    b = sensed(model, ctx, term, set_qpos(0, [2.0, -1.0]))
    close(term(b), [[math.sqrt(0**2 + 3**2 + 0.1**2)]])


def test_velocity_is_the_speed_of_the_frame(ctx):
    b = batch_of({SensorRequest("framelinvel", "box"): one_step((3, 4, 12), (0, 0, 0))})
    close(make(ctx, "velocity", a="box")(b), [[13.0], [0.0]])
    close(make(ctx, "velocity", a="box", axes="xy")(b), [[5.0], [0.0]])


# --- collision, contact_force (thesis Eq. 4.7) ----------------------------------------------------


def test_collision_is_zero_outside_the_margin_one_at_touching_and_sums_obstacles(ctx):
    term = make(ctx, "collision", a="robot", margin=0.1)
    assert term.obstacles == ("wall", "pillar")
    wall, pillar = term.sensors()
    # GEOMDIST reports the cutoff (= margin) when farther apart
    b = batch_of({wall: [[[0.1], [0.05], [0.0], [-0.02]]], pillar: [[[0.1], [0.1], [0.0], [0.1]]]})
    close(term(b), [[0.0, 0.5, 2.0, 1.2]])


def test_collision_excludes_its_own_frame_and_allows_no_obstacles(ctx):
    term = make(ctx, "collision", a="wall", obstacles=["wall"])
    assert term.obstacles == ()
    close(term(batch_of({pos("box"): [[[0, 0, 0]] * 3] * 2})), torch.zeros(2, 3))


def test_contact_force_is_the_net_force_against_each_fixed_obstacle(model, ctx):
    term = make(ctx, "contact_force", a="robot")
    assert term.obstacles == ("wall", "pillar")

    def press_on_wall(d):
        d.qpos[:2] = [0.69, 0.0]  # only the bumper, a child body, reaches the wall
        d.ctrl[:] = [5.0, 0.0]

    b = sensed(model, ctx, term, press_on_wall, steps=300)
    # at rest against the wall, the wall holds the 5 N motor force, all of it through the bumper:
    # the robot's contacts are those of its whole subtree
    assert abs(float(term(b)) - 5.0) < 1e-3
    close(torch.linalg.vector_norm(b.get(term.sensors()[1])), 0.0)


def test_contact_force_ignores_movable_objects_and_free_space(model, ctx):
    def push_box(d):
        d.qpos[:2] = [0.0, -0.3]  # touching the free box, far from wall and pillar
        d.ctrl[:] = [0.0, -5.0]

    fixed_only = make(ctx, "contact_force", a="robot")
    close(fixed_only(sensed(model, ctx, fixed_only, push_box, steps=3)), [[0.0]])
    # the push is real: named as an obstacle, the box reports its contact force
    with_box = make(ctx, "contact_force", a="robot", obstacles=["box"])
    assert float(with_box(sensed(model, ctx, with_box, push_box, steps=3))) > 0.1


def test_sparse_norm_is_the_norm_with_zero_vectors_at_a_vanishing_floor():
    forces = torch.zeros(50, 4, 7, 3, dtype=F64)
    forces[::5, :, 2] = torch.randn(10, 4, 3, dtype=F64)
    forces[1, 0, 0] = torch.tensor([1e-120, 0.0, 0.0])
    got, want = sparse_norm(forces), norm(forces)
    touching = want > 0
    assert torch.equal(got[touching], want[touching])  # bit for bit where not zero
    assert (got[~touching] == 1e-150).all()
    # a contact cost of untouched obstacles leaves any real cost it is added to unchanged
    untouched = 0.05 * sparse_norm(torch.zeros(7, 3, dtype=F64)).sum()  # 7 obstacles
    costs = torch.rand(50, 4, dtype=F64) + 1e-3
    assert torch.equal(costs + untouched, costs)


def test_collision_rejects_sites(ctx):
    # a site has no geoms: MuJoCo's distance sensor would not compile; the error names the key
    with pytest.raises(ConfigError, match=r"o\.terms\[0\]\.a: distances need a body"):
        make(ctx, "collision", a="site:left")


def test_contact_force_rejects_sites(ctx):
    with pytest.raises(ConfigError, match=r"o\.terms\[0\]\.a: contact forces need a body"):
        make(ctx, "contact_force", a="site:left")
    with pytest.raises(ConfigError, match=r"terms\[0\]\.obstacles\[1\]: no body named 'shelf'"):
        make(ctx, "contact_force", a="robot", obstacles=["wall", "shelf"])


# --- control_effort ------------------------------------------------------------------------------


def test_control_effort_over_all_or_named_channels(ctx):
    b = batch_of({pos("robot"): [[[0, 0, 0]] * 2]}, controls=[[[3.0, 4.0], [0.0, -1.0]]])
    close(make(ctx, "control_effort")(b), [[25.0, 1.0]])
    close(make(ctx, "control_effort", actuators=["uy"])(b), [[16.0, 1.0]])
    with pytest.raises(ConfigError, match=r"terms\[0\]\.actuators: unknown actuator.*'uz'"):
        make(ctx, "control_effort", actuators=["uz"])


# --- orientation (paper Eqs. 15, 33) --------------------------------------------------------------


def _yaw(deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def test_orientation_ignores_the_symmetries_of_a_cube(ctx):
    term = make(ctx, "orientation", a="box", b="goal")
    assert [(r.kind, r.obj, r.ref) for r in term.sensors()] == [
        (k, "goal", "box") for k in ("framexaxis", "frameyaxis", "framezaxis")
    ]
    h = math.sqrt(0.5)
    rotations = [_yaw(0), _yaw(90), _yaw(-180), (0.0, 1.0, 0.0, 0.0), (h, h, 0.0, 0.0), _yaw(45)]
    # the goal (world-aligned) in the box's frame: the columns of R_boxᵀ, the rows of R_box
    mats = np.zeros((len(rotations), 9))
    for mat, q in zip(mats, rotations):
        mujoco.mju_quat2Mat(mat, np.array(q, dtype=float))
    b = batch_of({r: one_step(*mats[:, 3 * i : 3 * i + 3]) for i, r in enumerate(term.sensors())})
    close(term(b), [[0.0]] * 5 + [[2.0 - math.sqrt(2.0)]])


def test_orientation_reads_the_real_frames(model, ctx):
    term = make(ctx, "orientation", a="box", b="goal")
    b = sensed(model, ctx, term, set_qpos(5, _yaw(45)))
    torch.testing.assert_close(term(b), torch.tensor([[2.0 - math.sqrt(2.0)]], dtype=F64))


# --- push_align, pull_align (paper Eqs. 16-18, 20) ------------------------------------------------

# object at the origin, goal 2 m ahead on x; robots: behind, between, beside, diagonally in
# front, diagonally behind, on the object
ROBOTS = [(-1, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (-1, 1, 0), (0, 0, 0)]


def _align_batch(robots=ROBOTS) -> RolloutBatch:
    n = len(robots)
    return batch_of(
        {
            pos("robot"): one_step(*robots),
            pos("box"): one_step(*[(0, 0, 0)] * n),
            pos("goal"): one_step(*[(2, 0, 0)] * n),
        }
    )


def test_push_align_is_zero_behind_the_object_and_one_between_object_and_goal(ctx):
    term = make(ctx, "push_align", a="robot", obj="box", goal="goal")
    close(term(_align_batch()), [[0.0], [1.0], [0.0], [math.sqrt(0.5)], [0.0], [0.0]])


def test_pull_align_is_the_mirror_of_push_align(ctx):
    term = make(ctx, "pull_align", a="robot", obj="box", goal="goal")
    close(term(_align_batch()), [[1.0], [0.0], [0.0], [0.0], [math.sqrt(0.5)], [0.0]])


def test_align_uses_the_planar_angle_unless_asked_for_3d(ctx):
    b = _align_batch([(1, 0, 5)])
    close(make(ctx, "push_align", a="robot", obj="box", goal="goal")(b), [[1.0]])
    close(
        make(ctx, "push_align", a="robot", obj="box", goal="goal", axes="xyz")(b),
        [[1 / math.sqrt(26)]],
    )


def test_align_with_the_object_on_the_goal_costs_nothing(ctx):
    b = batch_of(
        {
            pos("robot"): one_step((1, 0, 0)),
            pos("box"): one_step((2, 0, 0)),
            pos("goal"): one_step((2, 0, 0)),
        }
    )
    for name in ("push_align", "pull_align"):
        close(make(ctx, name, a="robot", obj="box", goal="goal")(b), [[0.0]])


# --- pull_direction (paper Eq. 21) ----------------------------------------------------------------


def test_pull_direction_penalises_controls_towards_the_object(ctx):
    # object 1 m along +x; actuators listed as (x, y) velocity although the channels are swapped
    term = make(ctx, "pull_direction", a="robot", obj="box", actuators=["uy", "ux"])
    assert term.channels == (1, 0)
    u_xy = [(1, 0), (-1, 0), (0, 1), (1, 1), (1, -1), (0, 0), (1e-9, 0)]
    controls = [[[uy, ux] for ux, uy in u_xy]]
    b = batch_of(
        {pos("robot"): [[[0, 0, 0.3]] * 7], pos("box"): [[[1, 0, 0.1]] * 7]}, controls=controls
    )
    h = math.sqrt(0.5)
    close(term(b), [[1.0, 0.0, 0.0, h, h, 0.0, 1.0]])


def test_pull_direction_within_counts_only_near_the_object(ctx):
    # driving straight at the object from 1.0, 0.5 and 0.4 m away; counted within 0.5 m only
    term = make(ctx, "pull_direction", a="robot", obj="box", actuators=["ux", "uy"], within=0.5)
    b = batch_of(
        {
            pos("robot"): [[[0, 0, 0.3], [0.5, 0, 0.3], [0.6, 0, 0.3]]],
            pos("box"): [[[1, 0, 0.1]] * 3],
        },
        controls=[[[1, 0]] * 3],
    )
    close(term(b), [[0.0, 1.0, 1.0]])
    with pytest.raises(ConfigError, match=r"terms\[0\]\.within"):
        make(ctx, "pull_direction", a="robot", obj="box", actuators=["ux", "uy"], within=0)


def test_pull_direction_needs_one_actuator_per_axis(ctx):
    with pytest.raises(ConfigError, match=r"terms\[0\]\.actuators: needs one velocity actuator"):
        make(ctx, "pull_direction", a="robot", obj="box", actuators=["ux"])
    with pytest.raises(ConfigError, match=r"terms\[0\]\.actuators: missing required key"):
        make(ctx, "pull_direction", a="robot", obj="box")
    with pytest.raises(ConfigError, match=r"terms\[0\]\.actuators: unknown actuator"):
        make(ctx, "pull_direction", a="robot", obj="box", actuators=["ux", "vel_y"])


# --- dynamic_obstacle (paper Eq. 22) --------------------------------------------------------------


def test_dynamic_obstacle_uses_the_rollouts_obstacle_position_at_each_step(ctx):
    term = make(ctx, "dynamic_obstacle", a="robot", obstacle="mover")
    r, p = term.sensors()
    T = 4
    moving = [[[1 + t, 0, 0] for t in range(T)]] * 2  # the rollout's predicted path
    riding = [[1 + t, 0, 0] for t in range(T)]  # exactly on it
    waiting = [[0, 0, 0]] * T
    b = batch_of({r: [riding, waiting], p: moving})
    close(term(b), [[1.0] * T, [math.exp(-(1 + t)) for t in range(T)]])


def test_dynamic_obstacle_prediction_matches_a_real_rollout(model, ctx):
    # a jointed obstacle coasting without friction moves at constant velocity in the rollout;
    # this also pins that rollout step 0 reports the initial state (sensors precede integration)
    term = make(ctx, "dynamic_obstacle", a="robot", obstacle="mover", axes="xy")
    spec = mujoco.MjSpec.from_string(MJCF)
    add_sensors(spec, term.sensors(), ctx.resolve)
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qvel[m.joint("mover_x").dofadr[0]] = 3.0
    mujoco.mj_forward(m, d)
    x0 = np.zeros(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, x0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    T = 5
    _, sd = mj_rollout.rollout(m, d, x0[None], np.zeros((1, T, m.nu)), nstep=T)
    b = RolloutBatch(
        torch.as_tensor(sd),
        torch.zeros(1, T, m.nu, dtype=F64),
        SensorColumns.of_model(m, term.sensors()),
        m.opt.timestep,
    )
    gap = [math.hypot(-2 + 3 * t * m.opt.timestep, 2) for t in range(T)]
    torch.testing.assert_close(term(b), torch.tensor([[math.exp(-g) for g in gap]], dtype=F64))


# --- reach (paper Eq. 27) -------------------------------------------------------------------------


def _reach_batch(term, z_ee: list) -> RolloutBatch:
    n = len(z_ee)
    ee, obj, zee, zobj = term.sensors()
    return batch_of(
        {
            ee: one_step(*[(0, 0, 0.3)] * n),
            obj: one_step(*[(0, 0, 0)] * n),
            zee: one_step(*z_ee),
            zobj: one_step(*[(0, 0, 1)] * n),
        }
    )


def test_reach_is_distance_plus_tilt_residual(ctx):
    term = make(ctx, "reach", ee="site:left", obj="box", theta=-1.0)
    # gripper pointing down on the box (also unnormalised), horizontal, pointing up
    close(
        term(_reach_batch(term, [(0, 0, -1), (0, 0, -2), (1, 0, 0), (0, 0, 1)])),
        [[0.3], [0.3], [1.3], [2.3]],
    )
    weighted = make(ctx, "reach", ee="site:left", obj="box", theta=0, tilt_weight=2.0)
    close(weighted(_reach_batch(weighted, [(0, 0, -1), (1, 0, 0)])), [[2.3], [0.3]])


def test_reach_tilt_is_minimal_at_theta(ctx):
    theta = -0.5
    term = make(ctx, "reach", ee="site:left", obj="box", theta=theta)
    angles = torch.linspace(0, math.pi, 181, dtype=F64)
    z_ee = torch.stack([torch.sin(angles), torch.zeros_like(angles), torch.cos(angles)], -1)
    cost = term(_reach_batch(term, z_ee.tolist()))[:, 0]
    best = int(cost.argmin())
    assert math.isclose(math.cos(float(angles[best])), theta, abs_tol=1e-12)
    close(cost[best], 0.3)


def test_reach_reads_the_real_z_axes(model, ctx):
    term = make(ctx, "reach", ee="hand", obj="box", theta=0.0)
    # the box tipped 90 degrees about x: its z axis lies horizontal, the hand's points up
    h = math.sqrt(0.5)
    b = sensed(model, ctx, term, set_qpos(2, [0, -0.5, 0.1, h, h, 0, 0]))
    torch.testing.assert_close(term(b), torch.tensor([[math.hypot(0.5, 0.3)]], dtype=F64))


def test_reach_with_obj_axis_up_takes_a_tipped_box_by_its_new_top_face(model, ctx):
    term = make(ctx, "reach", ee="hand", obj="box", theta=-1.0, obj_axis="up")
    eq27 = make(ctx, "reach", ee="hand", obj="box", theta=-1.0)
    h = math.sqrt(0.5)
    # upright: the same cost as Eq. 27's z axis; tipped 90 degrees about x (its -y axis now
    # points up): the hand pointing up is 2 (opposite) from the top face's -1, where Eq. 27's
    # flat z axis would call any hand pointing up or down half-way (1 off theta = -1)
    for quat, tilt_up, tilt_eq27 in ([1, 0, 0, 0], 2.0, 2.0), ([h, h, 0, 0], 2.0, 1.0):
        state = set_qpos(2, [0, -0.5, 0.1, *quat])
        b_up, b_27 = sensed(model, ctx, term, state), sensed(model, ctx, eq27, state)
        torch.testing.assert_close(
            term(b_up), torch.tensor([[math.hypot(0.5, 0.3) + tilt_up]], dtype=F64)
        )
        torch.testing.assert_close(
            eq27(b_27), torch.tensor([[math.hypot(0.5, 0.3) + tilt_eq27]], dtype=F64)
        )
    with pytest.raises(ConfigError, match=r"terms\[0\]\.obj_axis.*one of: up, z"):
        make(ctx, "reach", ee="hand", obj="box", theta=-1.0, obj_axis="x")


def test_top_axis_is_the_signed_axis_nearest_up():
    from planner_client.costs.poses import top_axis

    rot = torch.eye(3, dtype=F64)  # rows: x, y, z axes in the world
    torch.testing.assert_close(top_axis(rot), torch.tensor([0.0, 0.0, 1.0], dtype=F64))
    flipped = torch.tensor([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], dtype=F64)  # y points down
    torch.testing.assert_close(top_axis(flipped), torch.tensor([0.0, 0.0, 1.0], dtype=F64))
    batch = torch.stack([rot, flipped])[:, None]  # [2, 1, 3, 3]
    assert top_axis(batch).shape == (2, 1, 3)


def test_tilt_is_the_residual_of_eq_27_alone(ctx):
    term = make(ctx, "tilt", ee="site:left", obj="box", theta=-1.0)
    zee, zobj = term.sensors()
    # pointing down (also unnormalised), horizontal, up; the box's z axis up
    b = batch_of(
        {
            zee: one_step((0, 0, -1), (0, 0, -3), (1, 0, 0), (0, 0, 1)),
            zobj: one_step(*[(0, 0, 1)] * 4),
        }
    )
    close(term(b), [[0.0], [0.0], [1.0], [2.0]])
    level = make(ctx, "tilt", ee="site:left", obj="box", theta=0.0)
    close(level(b), [[1.0], [1.0], [0.0], [1.0]])


def test_approach_cone_keeps_the_hand_above_the_object_until_over_it(ctx):
    term = make(ctx, "approach_cone", ee="site:left", obj="box", slope=1.0, height=0.05)
    pee, pobj = term.sensors()
    # far and level with the box; far, 5 cm above; 2 cm off, 1 cm above; right over, at its centre
    b = batch_of(
        {
            pee: one_step((0.3, 0, 1.0), (0.3, 0, 1.05), (0.02, 0, 1.01), (0, 0, 1.0)),
            pobj: one_step(*[(0, 0, 1.0)] * 4),
        }
    )
    close(term(b), [[0.05], [0.0], [0.01], [0.0]])
    steep = make(ctx, "approach_cone", ee="site:left", obj="box", slope=2.0, height=0.05)
    close(steep(b), [[0.05], [0.0], [0.03], [0.0]])
    # a flat bottom 1.5 cm wide: 2 cm off is 0.5 cm past it
    flat = make(ctx, "approach_cone", ee="site:left", obj="box", radius=0.015, height=0.05)
    close(flat(b), [[0.05], [0.0], [0.0], [0.0]])


def test_approach_cone_rejects_a_non_positive_height_and_a_negative_radius(ctx):
    with pytest.raises(ConfigError, match=r"terms\[0\]\.height.*metres > 0"):
        make(ctx, "approach_cone", ee="site:left", obj="box", height=0.0)
    with pytest.raises(ConfigError, match=r"terms\[0\]\.radius.*metres >= 0"):
        make(ctx, "approach_cone", ee="site:left", obj="box", radius=-0.01)


def test_reach_theta_must_be_a_cosine(ctx):
    with pytest.raises(ConfigError, match=r"terms\[0\]\.theta: must be in \[-1, 1\].*1.5"):
        make(ctx, "reach", ee="hand", obj="box", theta=1.5)
    with pytest.raises(ConfigError, match=r"terms\[0\]\.theta: missing required key"):
        make(ctx, "reach", ee="hand", obj="box")


# --- gripper_width (paper Eqs. 28, 30) ------------------------------------------------------------


def test_gripper_width_closed_open_and_value(ctx):
    b = batch_of(
        {
            pos("site:left"): one_step((0, 0.03, 1), (0, 0, 1)),
            pos("site:right"): one_step((0, -0.03, 1), (0, 0, 1)),
        }
    )
    pair = dict(left="site:left", right="site:right")
    close(make(ctx, "gripper_width", target="closed", **pair)(b), [[0.06], [0.0]])
    close(make(ctx, "gripper_width", target="open", **pair)(b), [[0.94], [1.0]])
    close(make(ctx, "gripper_width", value=0.05, **pair)(b), [[0.01], [0.05]])


def test_gripper_width_reads_real_sites(model, ctx):
    term = make(ctx, "gripper_width", left="site:left", right="site:right", target="closed")
    torch.testing.assert_close(
        term(sensed(model, ctx, term, lambda d: None)), torch.tensor([[0.06]], dtype=F64)
    )


def test_gripper_width_needs_exactly_one_target(ctx):
    pair = dict(left="site:left", right="site:right")
    for params in ({}, {"target": "closed", "value": 0.05}):
        with pytest.raises(ConfigError, match=r"terms\[0\]\.target: give exactly one of"):
            make(ctx, "gripper_width", **pair, **params)
    with pytest.raises(ConfigError, match=r"terms\[0\]\.target: must be one of: closed, open"):
        make(ctx, "gripper_width", target="shut", **pair)


# --- joint_limits, posture -----------------------------------------------------------------------


def joint(name: str) -> SensorRequest:
    return SensorRequest("jointpos", name)


def test_joint_limits_cost_nothing_inside_the_margin_and_one_per_joint_at_a_limit(ctx):
    term = make(ctx, "joint_limits", joints=["y"], margin=0.2)
    # mid-range; 0.1 into the margin; at the upper limit; 0.1 past the lower one
    b = batch_of({joint("y"): one_step((0.0,), (0.4,), (0.5,), (-0.6,))})
    close(term(b), [[0.0], [0.5], [1.0], [1.5]])


def test_joint_limits_reads_the_real_joint(model, ctx):
    term = make(ctx, "joint_limits", joints=["y"], margin=0.2)
    close(term(sensed(model, ctx, term, set_qpos(1, [0.45]))), [[0.75]])


def test_joint_limits_refuses_unknown_unlimited_or_no_joints(ctx):
    with pytest.raises(
        ConfigError,
        match=r"terms\[0\]\.joints: not a joint of the robot "
        r"\(got 'z'; expected one of: x, y\)",
    ):
        make(ctx, "joint_limits", joints=["z"])
    with pytest.raises(ConfigError, match=r"joint has no range in the model \(got 'x'"):
        make(ctx, "joint_limits", joints=["x"])
    with pytest.raises(ConfigError, match=r"no joints to cost: the robot has no limited hinge"):
        make(ctx, "joint_limits")  # the base has slides only


def test_posture_is_the_squared_distance_to_the_start_pose_or_a_target(ctx):
    b = batch_of({joint("x"): one_step((0.0,), (1.0,)), joint("y"): one_step((0.1,), (0.4,))})
    close(make(ctx, "posture", joints=["x", "y"])(b), [[0.0], [1.0 + 0.09]])
    close(make(ctx, "posture", joints=["x", "y"], target=[1.0, 0.0])(b), [[1.01], [0.16]])
    with pytest.raises(ConfigError, match=r"terms\[0\]\.target.*2 joint positions"):
        make(ctx, "posture", joints=["x", "y"], target=[1.0])


# --- every term: sensors compile into a model ----------------------------------------------------

EXAMPLES = {
    "distance": dict(a="robot", b="goal"),
    "collision": dict(a="robot"),
    "control_effort": dict(),
    "velocity": dict(a="box"),
    "orientation": dict(a="box", b="goal"),
    "push_align": dict(a="robot", obj="box", goal="goal"),
    "pull_align": dict(a="robot", obj="box", goal="goal"),
    "pull_direction": dict(a="robot", obj="box", actuators=["ux", "uy"]),
    "dynamic_obstacle": dict(a="robot", obstacle="mover"),
    "reach": dict(ee="site:left", obj="box", theta=-1.0),
    "tilt": dict(ee="site:left", obj="box", theta=-1.0),
    "approach_cone": dict(ee="site:left", obj="box", radius=0.02),
    "gripper_width": dict(left="site:left", right="site:right", target="open"),
    "contact_force": dict(a="robot"),
    "joint_limits": dict(joints=["y"]),
    "posture": dict(joints=["x", "y"]),
    "clearance": dict(a="robot", margin=0.1),
    "perceived_clearance": dict(margin=0.1),
    "guide_progress": dict(),
    "guide_distance": dict(),
    "guide_handle": dict(a="robot"),
}


def test_every_registered_term_has_an_example():
    assert set(EXAMPLES) == set(TERMS)


def test_all_terms_together_compile_and_give_finite_costs_at_rest(model, ctx):
    terms = [make(ctx, name, **params) for name, params in EXAMPLES.items()]
    requests = [r for t in terms for r in t.sensors()]
    spec = mujoco.MjSpec.from_string(MJCF)
    # perceived_clearance reads sites at its spheres, which the planner adds only for it
    add_sphere_sites(spec, robot_spheres(model, ctx.resolve), {r.obj for r in requests})
    add_sensors(spec, requests, ctx.resolve)
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    sd = torch.as_tensor(np.tile(d.sensordata, (3, 4, 1)))
    b = RolloutBatch(
        sd, torch.zeros(3, 4, m.nu, dtype=F64), SensorColumns.of_model(m, requests), 0.01
    )
    for term in terms:
        cost = term(b)
        assert cost.shape == (3, 4) and torch.isfinite(cost).all(), term.name


# --- objectives: weights, when, YAML errors ------------------------------------------------------


def _objective(ctx, *terms: dict):
    cfgs = []
    for i, t in enumerate(terms):
        params = {k: v for k, v in t.items() if k not in ("term", "weight")}
        cfgs.append(
            TermConfig(
                term=t["term"],
                weight=t.get("weight", 1.0),
                params=params,
                path=f"objectives.push.terms[{i}]",
            )
        )
    return build_objective("push", ObjectiveConfig(terms=tuple(cfgs)), ctx)


def test_objective_weights_and_running_terminal_masks(ctx):
    dist = {"term": "distance", "a": "robot", "b": "goal"}
    obj = _objective(
        ctx,
        {**dist, "weight": 2.0},
        {**dist, "weight": 10.0, "when": "terminal"},
        {"term": "velocity", "a": "robot", "when": "running"},
    )
    b = batch_of(
        {
            pos("robot"): [[[0, 0, 0]] * 3],
            pos("goal"): [[[3, 4, 0]] * 3],
            SensorRequest("framelinvel", "robot"): [[[1, 0, 0]] * 3],
        }
    )
    close(obj(b), [[11.0, 11.0, 60.0]])


def _random_batch(obj, samples: int = 6, horizon: int = 4, seed: int = 0) -> RolloutBatch:
    """Random sensor values for every request of ``obj``, a third of them exactly zero (an
    untouched obstacle's contact force), laid out in shuffled order."""
    rng = np.random.default_rng(seed)
    reqs = list(dict.fromkeys(obj.sensors()))
    rng.shuffle(reqs)
    values = {}
    for r in reqs:
        v = rng.normal(size=(samples, horizon, r.dim)) * 10.0 ** rng.integers(-3, 4)
        v[rng.random((samples, horizon)) < 0.33] = 0.0
        values[r] = v.tolist()
    return batch_of(values, controls=np.zeros((samples, horizon, 2)))


def test_an_objective_of_norms_costs_what_its_terms_sum_to(ctx):
    """Distances (with an offset, along some axes, listed twice), a speed and contact forces:
    the fused evaluation (:mod:`planner_client.costs.norms`) against each term's own."""
    obj = _objective(
        ctx,
        {"term": "distance", "a": "robot", "b": "goal", "axes": "xy", "weight": 1.5},
        {
            "term": "distance",
            "a": "robot",
            "b": "goal",
            "axes": "xy",
            "weight": 4.0,
            "when": "terminal",
        },
        {"term": "distance", "a": "hand", "b": "box", "offset": [0.1, -0.2, 0.3], "weight": 2.0},
        {"term": "velocity", "a": "robot", "axes": "z", "when": "running", "weight": 0.3},
        {"term": "contact_force", "a": "robot", "weight": 0.05},
    )
    assert fusable([wt.term for wt in obj.terms])
    for seed in range(3):
        batch = _random_batch(obj, seed=seed)
        fused, per_term = obj(batch), obj(batch, {})
        torch.testing.assert_close(fused, per_term, rtol=1e-12, atol=0.0)
    # the sensor columns are part of the fused form: another batch's columns are read where they are
    other = _random_batch(obj, seed=7)
    torch.testing.assert_close(obj(other), obj(other, {}), rtol=1e-12, atol=0.0)


class _NormsOnly:
    """A term that is only its norms (what :class:`NormObjective` reads of a term)."""

    def __init__(self, *norms: Norm):
        self._norms = list(norms)

    def norms(self) -> list[Norm]:
        return self._norms


def _dense_reference(terms, columns: SensorColumns, x: np.ndarray) -> np.ndarray:
    """The objective of ``terms`` over ``x [S, T, n]`` as the module's equation reads, one norm
    at a time in NumPy: ``Σ_g W[t, g] sqrt(max(floor, Σ_i (b_i + Σ c x)²))``."""
    out = np.zeros(x.shape[:2])
    for term, w in terms:
        for each in term.norms():
            squares = 0.0
            for bias, parts in each.components:
                z = bias + sum(c * x[..., columns.spans[req].start + i] for req, i, c in parts)
                squares = squares + z * z
            out += w.numpy() * np.sqrt(np.maximum(each.floor, squares))
    return out


def test_fused_norms_of_any_shape_are_what_the_equation_says():
    """Components with a bias and two values (the first negative), one value scaled by 2.5, a
    column listed twice and one whose coefficients cancel, norms of one to three components:
    the fused evaluation against :mod:`planner_client.costs.norms`' equation."""
    a, b = SensorRequest("framepos", "a"), SensorRequest("framepos", "b")
    columns = SensorColumns({b: slice(0, 3), a: slice(3, 6)})
    distance = Norm(tuple((0.1 * i, ((a, i, -1.0), (b, i, 1.0))) for i in range(3)))
    odd = Norm(
        ((0.0, ((a, 0, 2.5),)), (-0.3, ((b, 1, 1.0), (b, 1, 1.0), (a, 2, 1.0)))), floor=1e-300
    )
    gone = Norm(((0.5, ((a, 1, 1.0), (a, 1, -1.0))),))
    terms = [
        (_NormsOnly(distance, gone), torch.tensor([1.0, 2.0, 3.0], dtype=F64)),
        (_NormsOnly(odd), torch.tensor([0.5, 0.0, 4.0], dtype=F64)),
    ]
    x = np.random.default_rng(3).normal(size=(7, 3, 6)) * 10.0 ** np.arange(-2, 4)
    x[0, 0] = 0.0
    got = NormObjective(terms, columns, 6)(torch.from_numpy(x.copy()))
    np.testing.assert_allclose(got.numpy(), _dense_reference(terms, columns, x), rtol=1e-13)


def test_norms_of_unit_differences_are_exact():
    """A distance, ``x_a - x_b`` with or without an offset, is the number plain differences
    give, bit for bit, whatever the BLAS: its map's products are by ±1 or 0, exact."""
    a, b = SensorRequest("framepos", "a"), SensorRequest("framepos", "b")
    columns = SensorColumns({a: slice(0, 3), b: slice(3, 6)})
    plain = Norm(tuple((0.0, ((a, i, 1.0), (b, i, -1.0))) for i in range(2)))
    offset = Norm(((0.25, ((b, 2, -1.0),)),))
    ones = torch.ones(4, dtype=F64)
    objective = NormObjective([(_NormsOnly(plain, offset), ones)], columns, 6)
    x = np.random.default_rng(5).normal(size=(50, 4, 6)) * 1e3
    got = objective(torch.from_numpy(x.copy())).numpy()
    dx, dy = x[..., 0] - x[..., 3], x[..., 1] - x[..., 4]
    squares = torch.from_numpy(np.stack([dx * dx + dy * dy, (0.25 - x[..., 5]) ** 2]))
    want = squares.sqrt().sum(0)  # torch's root: not always correctly rounded, as NumPy's is
    assert np.array_equal(got, want.numpy())


def test_an_objectives_norm_terms_are_fused_beside_its_other_terms(ctx):
    obj = _objective(
        ctx,
        {"term": "distance", "a": "robot", "b": "goal", "weight": 2.0},
        {"term": "collision", "a": "robot", "weight": 3.0},
        {"term": "contact_force", "a": "robot", "weight": 0.1, "when": "running"},
        {"term": "orientation", "a": "base", "b": "box"},
    )
    assert not fusable([wt.term for wt in obj.terms])
    fused, rest = obj._split(_random_batch(obj))
    assert fused is not None and [term.name for term, _ in rest] == ["collision", "orientation"]
    for seed in range(3):
        batch = _random_batch(obj, seed=seed)
        torch.testing.assert_close(obj(batch), obj(batch, {}), rtol=1e-12, atol=0.0)


def test_one_norm_term_beside_others_is_evaluated_on_its_own(ctx):
    """Fusing a single norm would take as many operations as the term itself."""
    obj = _objective(
        ctx, {"term": "distance", "a": "robot", "b": "goal"}, {"term": "collision", "a": "robot"}
    )
    batch = _random_batch(obj)
    fused, rest = obj._split(batch)
    assert fused is None and [term.name for term, _ in rest] == ["distance", "collision"]
    torch.testing.assert_close(obj(batch), obj(batch, {}), rtol=0.0, atol=0.0)


@pytest.mark.parametrize(
    "term, message",
    [
        (
            {"term": "push_allign", "a": "robot"},
            r"test\.yaml: objectives\.push\.terms\[1\]\.term: "
            r"unknown cost term \(got 'push_allign'; "
            r"expected one of: .*push_align",
        ),
        (
            {"term": "push_align", "a": "robot", "obj": "box", "goal": "goal", "gaol": "goal"},
            r"test\.yaml: objectives\.push\.terms\[1\]\.gaol: "
            r"unknown key \(expected one of: .*goal",
        ),
        (
            {"term": "push_align", "a": "robot", "obj": "crate", "goal": "goal"},
            r"test\.yaml: objectives\.push\.terms\[1\]\.obj: "
            r"no body named 'crate'.*expected one of: "
            r"robot, base, bumper, hand, wall, .*site:left",
        ),
        (
            {"term": "orientation", "a": "box", "b": "site:tip"},
            r"test\.yaml: objectives\.push\.terms\[1\]\.b: no site named 'tip'",
        ),
        (
            {"term": "distance", "a": "robot", "b": "goal", "when": "final"},
            r"test\.yaml: objectives\.push\.terms\[1\]\.when: "
            r"must be one of: all, running, terminal "
            r"\(got 'final'\)",
        ),
        (
            {"term": "gripper_width", "left": "site:left", "right": "site:right", "value": -0.1},
            r"test\.yaml: objectives\.push\.terms\[1\]\.value: must be >= 0",
        ),
    ],
)
def test_yaml_errors_name_the_key_path(ctx, term, message):
    with pytest.raises(ConfigError, match=message):
        _objective(ctx, {"term": "distance", "a": "robot", "b": "goal"}, term)
