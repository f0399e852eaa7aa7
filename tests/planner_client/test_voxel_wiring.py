"""The 3-D map wired into the planner (planner_client/maps.py, issue 56): a scenario with a depth
camera and no lidar gets a voxel map over the arm's workspace, which the ``perceived_clearance``
term reads (the robot's spheres and a carried object's); ``planner.map``'s keys are checked; the
declared solids that reach into the box are composed; and over an episode the map holds the
block the camera sees and never the robot, the cubes or the cube in the hand."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
import torch

from planner_client.build import build_controller
from planner_client.costs import RolloutBatch
from planner_client.maps import default_box, known_solids, map_sensors, map_settings
from planner_client.perception.grid import GridSpec
from planner_client.perception.voxels import VoxelGrid
from planner_client.problem import build_problem
from planner_client.spheres import robot_bodies
from server.inprocess import build_episode, run_episode
from shared.config import ConfigError
from shared.scenario import load_scenario, parse_scenario
from tests.helpers import play

F64 = torch.float64
RES = 0.02


@pytest.fixture(scope="module")
def seen():
    return load_scenario("pick_place_seen")


def block_of(scenario) -> tuple[np.ndarray, np.ndarray]:
    block = next(o for o in scenario.world.objects if o.name == "block")
    return np.array(block.pos), np.array(block.size)


def with_map(scenario, **keys):
    planner = dataclasses.replace(scenario.planner, map=keys)
    return dataclasses.replace(scenario, planner=planner)


def carry_term(problem):
    """move2place_seen's perceived_clearance: the one with the carried cube's sphere."""
    return next(
        e.term
        for o in problem.objectives.values()
        for e in o.terms
        if e.term.name == "perceived_clearance" and e.term.objects
    )


def cube_batch(problem, positions: np.ndarray) -> RolloutBatch:
    """The problem's sensor values with cube_a at each of ``positions [S, T, 3]`` (the robot at
    its start, far above the table)."""
    model = problem.model
    data = mujoco.MjData(model)
    adr = model.jnt_qposadr[model.body("cube_a").jntadr[0]]
    rows = []
    for p in positions.reshape(-1, 3):
        data.qpos[adr : adr + 3] = p
        mujoco.mj_forward(model, data)
        rows.append(data.sensordata.copy())
    sd = torch.tensor(np.array(rows), dtype=F64).reshape(*positions.shape[:2], -1)
    controls = torch.zeros(*positions.shape[:2], model.nu, dtype=F64)
    return RolloutBatch(sd, controls, problem.columns, 0.01)


def test_a_depth_camera_gives_a_3d_map_that_the_term_reads(seen):
    controller = build_controller(seen, seed=0, threads=2)
    episode = build_episode(seen, seed=0)
    try:
        controller.begin("lockstep", episode.dt)
        play(controller, episode, 3)
        assert isinstance(controller.map.map, VoxelGrid)
        field = controller.map.latest()
        assert field is not None and field.dims == 3
        problem = controller.motion.problem
        term = carry_term(problem)
        assert term.source.latest() is field
        pos, size = block_of(seen)
        top = pos + [0.0, 0.0, size[2]]
        cube = np.array(seen.world.objects[1].pos)  # cube_a, filtered out of the map
        d = field.lookup(torch.tensor(np.array([pos, top, cube]))).numpy()
        assert d[0] < RES and d[1] < RES and d[2] > 0.1
        radius = term.object_radii[0]
        assert radius == pytest.approx(0.025 * math.sqrt(3))
        # cube_a resting on the block's top, and 0.3 m above it
        batch = cube_batch(problem, np.array([[top + [0, 0, 0.025], top + [0, 0, 0.3]]]))
        cost = term(batch)
        assert cost.shape == (1, 2) and cost[0, 0] >= 1.0 and cost[0, 1] == 0.0
    finally:
        controller.close()
        episode.close()
    assert problem.field_source.latest() is None


@pytest.mark.parametrize(
    "name, keys, path, message",
    [
        ("pick_place_seen", {"dims": 2}, "planner.map.dims", "reads lidars"),
        ("pick_place_seen", {"dims": 4}, "planner.map.dims", "must be 2 or 3"),
        ("navigation_seen", {"box": [[0, 0, 0], [1, 1, 1]]}, "planner.map.box", "3-D map's key"),
        ("pick_place_seen", {"box": [[0, 0, 1], [1, 1, 0.5]]}, "planner.map.box", "below"),
        ("pick_place_seen", {"box": [[0, 0, 1]]}, "planner.map.box", "two corners"),
        ("pick_place_seen", {"padding": -0.01}, "planner.map.padding", ">= 0"),
        ("pick_place_seen", {"resolution": 0.02, "size": 3}, "planner.map.size", "unknown key"),
    ],
)
def test_planner_map_keys_are_checked(name, keys, path, message):
    with pytest.raises(ConfigError) as exc:
        map_settings(with_map(load_scenario(name), **keys))
    assert exc.value.path == path and message in str(exc.value), str(exc.value)


def test_a_lidar_scenario_keeps_its_2d_map_unless_dims_says_3():
    nav = load_scenario("navigation_seen")
    assert map_settings(nav).dims == 2 and map_sensors(nav) == ["lidar"]
    voxels = with_map(nav, dims=3, resolution=0.1)
    assert map_settings(voxels).dims == 3 and map_sensors(voxels) == ["lidar"]
    assert map_sensors(load_scenario("pick_place")) == []  # no sensors: no map


def test_the_default_box_holds_the_arms_reach_above_the_table(seen):
    problem = build_problem(with_map(seen))
    lo, hi = (np.array(c) for c in default_box(problem, 0.05))
    assert lo[2] == pytest.approx(1.0 + 0.025)  # the table's top, and half a cell
    model, data = problem.model, mujoco.MjData(problem.model)
    robot = robot_bodies(model, problem.resolve)
    geoms = np.isin(model.geom_bodyid, robot)
    rng = np.random.default_rng(0)
    lo_q, hi_q = model.jnt_range[:7].T
    for _ in range(50):
        data.qpos[:7] = rng.uniform(lo_q, hi_q)
        mujoco.mj_kinematics(model, data)
        reach = model.geom_rbound[geoms][:, None]
        assert np.all(data.geom_xpos[geoms] - reach >= [*lo[:2], -np.inf])
        assert np.all(data.geom_xpos[geoms] + reach <= hi)


def test_declared_solids_that_reach_into_the_box_are_composed_and_the_table_is_not(seen):
    raw = load_scenario("pick_place_seen").raw
    raw.pop("base", None)
    raw = {**raw, "world": {**raw["world"], "objects": [dict(o) for o in raw["world"]["objects"]]}}
    raw["world"]["objects"][-1]["perceived"] = False  # the block, declared
    declared = build_problem(parse_scenario(raw, "declared.yaml"))
    spec = GridSpec.box((-0.25, -0.45, 1.01), (0.45, 0.45, 1.41), RES)
    field = known_solids(declared, spec)
    pos, size = block_of(seen)
    points = torch.tensor(np.array([pos, pos + [0.0, 0.0, size[2] + 0.1], [0.3, -0.35, 1.02]]))
    d = field.lookup(points).numpy()
    assert d[0] < 0.0 and d[1] == pytest.approx(0.1, abs=1e-6) and d[2] > 0.3
    assert known_solids(build_problem(seen), spec) is None  # the table only touches the box


@pytest.mark.parametrize(
    "objects, message",
    [
        (["panda_hand"], "a body of the robot"),
        (["nothing"], "nothing"),
        (["site:grasp"], "not a body"),
    ],
)
def test_the_terms_objects_are_bodies_of_the_model_not_the_robots(seen, objects, message):
    raw = load_scenario("pick_place_seen").raw
    raw.pop("base", None)
    term = {"term": "perceived_clearance", "margin": 0.03, "objects": objects}
    raw["objectives"] = {
        **raw["objectives"],
        "move2place_seen": {"extends": "move2place", "terms": [term]},
    }
    with pytest.raises(ConfigError) as exc:
        build_problem(parse_scenario(raw, "t.yaml"))
    assert "objects[0]" in exc.value.path and message in str(exc.value), str(exc.value)


@pytest.mark.slow
def test_over_an_episode_the_map_holds_the_block_and_never_the_arm_or_the_cubes(seen):
    pos, size = block_of(seen)
    controller = None
    counts = []

    def planner(sc, seed):
        nonlocal controller
        controller = build_controller(sc, seed=seed, threads=2)
        return controller

    def check(state, command):
        grid = controller.map.map
        if grid.scans == 0:
            return
        centres = grid.spec.centres()[grid.occupied()]
        off = np.abs(centres - pos) - size  # > 0 outside the block, along each axis
        # every voxel held is one the block's surface passes through
        assert np.all(off <= RES / 2 + 1e-9), centres[np.any(off > RES / 2 + 1e-9, axis=1)]
        counts.append(len(centres))

    result = run_episode(seen, planner, seed=0, on_step=check)
    assert result.outcome.time > 2.5  # it reached the carry
    assert min(counts) >= 0.9 * max(counts) and max(counts) >= 10
