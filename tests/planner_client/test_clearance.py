"""The clearance term (planner_client/costs/clearance.py) and its planar distances
(planner_client/costs/planar.py): the cost's shape, the planar distances against MuJoCo's
distance sensors in navigation's scene and in a model with fixed obstacles, and the fall back
to the sensors where the problem is not planar."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from planner_client.costs import TERMS, RolloutBatch, TermContext
from planner_client.problem import build_problem, obstacle_names
from planner_client.sensors import SensorColumns, add_sensors
from shared.config import ConfigError, Section
from shared.frames import FrameResolver
from shared.scenario import load_scenario
from shared.scene import build_spec, compile_model
from tests.planner_client.test_cost_terms import MJCF  # the cost-term tests' small model

F64 = torch.float64
MARGIN = 0.1


def _term(ctx: TermContext, **params):
    s = Section(params, "t.yaml", "objectives.o.terms[0]")
    term = TERMS["clearance"].from_params(s, ctx)
    s.done()
    return term


def test_clearance_is_zero_beyond_the_margin_one_at_touching_and_steeper_inside():
    model = mujoco.MjModel.from_xml_string(MJCF)
    ctx = TermContext("t.yaml", FrameResolver(model, "base"), ["wall"], ["ux", "uy"])
    term = _term(ctx, a="base", margin=0.2, method="sensors")
    (req,) = term.requests
    d = torch.tensor([[[0.3], [0.2], [0.1], [0.0], [-0.1]]], dtype=F64)  # [1, 5, 1] distances
    batch = RolloutBatch(d, torch.zeros(1, 5, 2, dtype=F64), SensorColumns({req: slice(0, 1)}), 0.1)
    torch.testing.assert_close(term(batch), torch.tensor([[0.0, 0.0, 0.25, 1.0, 2.25]], dtype=F64))
    with pytest.raises(ConfigError, match="margin"):  # the margin is declared, never defaulted
        TERMS["clearance"].from_params(Section({"a": "base"}, "t.yaml", "o"), ctx)


def _both(spec: mujoco.MjSpec, base: mujoco.MjModel, ctx: TermContext, **params):
    """The planar and the sensor term, and the model compiled with both terms' sensors."""
    planar = _term(ctx, method="planar", margin=MARGIN, **params)
    sensors = _term(ctx, method="sensors", margin=MARGIN, **params)
    assert (planar.method, sensors.method) == ("planar", "sensors")
    requests = planar.requests + sensors.requests
    add_sensors(spec, requests, ctx.resolve)
    return planar, sensors, requests


def _compare(planar, sensors, sensordata: np.ndarray, columns: SensorColumns) -> None:
    """Within 1 mm where MuJoCo's reading is inside the cutoff and above −margin (where it
    stops: the planar value goes on with the horizontal depth), at least the margin (cost 0)
    where MuJoCo reads the cutoff; the costs the same there."""
    # one sample of many steps: the planar term reads the mocap bodies from the first sample
    # (they move alike in every sample), and here they move from step to step
    sd = torch.as_tensor(sensordata)[None]  # [1, T, nsensordata]
    batch = RolloutBatch(sd, torch.zeros(1, sd.shape[1], 2, dtype=F64), columns, 0.1)
    d_planar, d_mujoco = planar.distances(batch), sensors.distances(batch)  # [1, T, n]
    near = (d_mujoco < MARGIN - 1e-9) & (d_mujoco > -MARGIN + 1e-9)
    far = d_mujoco >= MARGIN - 1e-9
    assert near.sum() > 100 and far.sum() > 100  # both cases seen, many times
    assert (d_planar - d_mujoco)[near].abs().max() < 1e-3
    assert d_planar[far].min() >= MARGIN - 1e-9
    # the cost alike wherever the robot's centre is outside every footprint
    outside = (d_planar > -planar.planar.radius).all(-1) & (d_mujoco > -MARGIN + 1e-9).all(-1)
    torch.testing.assert_close(planar(batch)[outside], sensors(batch)[outside], atol=0.05, rtol=0)


def test_planar_distances_are_mujocos_in_navigations_scene_with_its_blocks_moved_and_turned():
    sc = load_scenario("navigation_clear")
    spec = build_spec(sc)
    base = compile_model(sc, spec.copy())
    ctx = TermContext("t.yaml", FrameResolver(base, sc.robot.spec.frame), obstacle_names(sc), [])
    planar, sensors, requests = _both(spec, base, ctx, a="robot")
    assert planar.planar.moving == ("block_a", "block_b", "pillar")  # mocap: read every step
    model = compile_model(sc, spec)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(3000):
        mujoco.mj_resetData(model, data)
        data.qpos[:2] = rng.uniform(-3.9, 3.9, 2)
        if k % 2:  # the blocks moved and turned (a disturbance, the move op)
            yaw = rng.uniform(-np.pi, np.pi, model.nmocap)
            data.mocap_pos[:, :2] += rng.uniform(-0.5, 0.5, (model.nmocap, 2))
            data.mocap_quat[:] = np.stack(
                [np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1
            )
        mujoco.mj_forward(model, data)
        rows.append(data.sensordata.copy())
    _compare(planar, sensors, np.array(rows), SensorColumns.of_model(model, requests))


def test_planar_distances_are_mujocos_against_fixed_boxes_and_cylinders():
    spec = mujoco.MjSpec.from_string(MJCF)
    spec.worldbody.add_body(name="turned", pos=[0.0, 1.0, 0.1], quat=[0.92388, 0, 0, 0.38268])
    spec.body("turned").add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.3, 0.05, 0.1])
    base = spec.copy().compile()
    ctx = TermContext("t.yaml", FrameResolver(base, "base"), ["wall", "pillar", "turned"], [])
    planar, sensors, requests = _both(spec, base, ctx, a="base")
    assert planar.planar.moving == ()  # fixed to the world: constants
    model = spec.compile()
    data = mujoco.MjData(model)
    rows = []
    for xy in np.random.default_rng(1).uniform(-1.5, 1.5, (3000, 2)):
        data.qpos[:2] = xy
        mujoco.mj_forward(model, data)
        rows.append(data.sensordata.copy())
    _compare(planar, sensors, np.array(rows), SensorColumns.of_model(model, requests))


@pytest.mark.parametrize(
    "a, obstacles, reason",
    [
        ("base", ["wall", "box"], "'box' has a joint"),  # a free box: it moves and may tilt
        ("base", ["wall", "mover"], "'mover' has a joint"),
        ("wall", ["pillar"], "not a sphere, cylinder or capsule"),  # a box-shaped body
        ("hand", ["wall"], "no collision geom"),  # an arm's hand, drawn only
    ],
)
def test_what_is_not_planar_keeps_the_sensors_and_says_why_when_planar_is_declared(
    a, obstacles, reason
):
    model = mujoco.MjModel.from_xml_string(MJCF)
    ctx = TermContext("t.yaml", FrameResolver(model, "base"), ["wall"], ["ux", "uy"])
    auto = _term(ctx, a=a, obstacles=obstacles, margin=MARGIN)
    assert auto.method == "sensors" and auto.planar is None
    assert [r.kind for r in auto.requests] == ["distance"] * len(obstacles)
    with pytest.raises(ConfigError, match=rf"terms\[0\]\.method.*({reason})"):
        _term(ctx, a=a, obstacles=obstacles, margin=MARGIN, method="planar")


def test_obstacles_above_the_robot_keep_the_sensors():
    spec = mujoco.MjSpec.from_string(MJCF)
    spec.worldbody.add_body(name="shelf", pos=[0.5, 0.0, 0.6])  # above the base's 0-0.2 m
    spec.body("shelf").add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.2, 0.2, 0.02])
    model = spec.compile()
    ctx = TermContext("t.yaml", FrameResolver(model, "base"), ["wall"], ["ux", "uy"])
    assert _term(ctx, a="base", obstacles=["shelf"], margin=MARGIN).method == "sensors"
    with pytest.raises(ConfigError, match="do not overlap"):
        _term(ctx, a="base", obstacles=["shelf"], margin=MARGIN, method="planar")


@pytest.mark.parametrize(
    "name", ["navigation_clear", "battery_enough_clear", "navigation_trap_guided"]
)
def test_the_shipped_clearance_scenarios_measure_in_the_plane(name):
    problem = build_problem(load_scenario(name))
    objectives = problem.objectives.values()
    terms = [wt.term for o in objectives for wt in o.terms if wt.term.name == "clearance"]
    assert terms and all(t.method == "planar" for t in terms)
    assert not any(r.kind == "distance" for r in problem.columns.spans)
