"""The 3-D map of an arm's workspace (issue 56): depth images the world simulates
(server/sensors.py) fused into voxels, their signed distance field against MuJoCo's own
distances, an obstacle that moves away cleared, known solids measured exactly, and the
self-filter that keeps the robot and the objects the planner models out of the map."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
import torch

from planner_client.maps import SelfFilter
from planner_client.perception.grid import GridSpec
from planner_client.perception.occupancy import MapConfig, Rays
from planner_client.perception.sdf import Solid, distance_field, solid_field
from planner_client.perception.self_filter import clip_rays
from planner_client.perception.voxels import VoxelGrid
from planner_client.problem import build_problem
from server.world import SimWorld
from shared.scans import Scan
from shared.scenario import load_scenario
from shared.scenario.sensors import DepthConfig

RES = 0.02
CFG = MapConfig(resolution=RES)


@pytest.fixture(scope="module")
def seen():
    return load_scenario("pick_place_seen")


def cameras_round(target, radius: float = 0.7, height: float = 0.45, n: int = 4) -> tuple:
    """``n`` depth cameras on a circle round ``target``, ``height`` above it, looking at it."""
    out = []
    for i in range(n):
        a = 2 * math.pi * (i + 0.5) / n
        pos = (target[0] + radius * math.cos(a), target[1] + radius * math.sin(a))
        out.append(
            DepthConfig(
                name=f"cam{i}",
                pos=(*pos, target[2] + height),
                look_at=tuple(target),
                width=96,
                height=72,
                range=(0.1, 3.0),
            )
        )
    return tuple(out)


def with_sensors(scenario, sensors):
    return dataclasses.replace(scenario, sensors=tuple(sensors))


def readings(world: SimWorld) -> list[Scan]:
    """One reading of each of the world's sensors in its current state."""
    rs = world.sensors
    return [rs.read(s, world.model, world.data) for s in rs.sensors]


def mirror(problem, world: SimWorld) -> mujoco.MjData:
    """The planner's scene of the world's state: its model has the same joints (the perceived
    block is a mocap body the planner's model lacks)."""
    data = mujoco.MjData(problem.model)
    data.qpos[:] = world.data.qpos
    mujoco.mj_kinematics(problem.model, data)
    return data


def block_of(scenario) -> tuple[np.ndarray, np.ndarray]:
    block = next(o for o in scenario.world.objects if o.name == "block")
    return np.array(block.pos), np.array(block.size)


def mujoco_distance(pos, size, points: np.ndarray) -> np.ndarray:
    """MuJoCo's distance ``[N]`` from each point to a box (a tiny probe sphere, mj_geomDistance)."""
    at, half = " ".join(map(str, pos)), " ".join(map(str, size))
    xml = f"""
    <mujoco><worldbody>
      <geom name="box" type="box" pos="{at}" size="{half}"/>
      <body name="probe" mocap="true"><geom name="probe" type="sphere" size="0.0005"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        data.mocap_pos[0] = p
        mujoco.mj_kinematics(model, data)
        out[i] = mujoco.mj_geomDistance(model, data, 1, 0, 10.0, None)
    return out + 0.0005


def voxels_near(grid: VoxelGrid, lo, hi, pad: float = 0.0) -> np.ndarray:
    """``grid.spec.shape`` bool: the voxels whose centres lie in the box ``lo`` - ``hi``
    grown by ``pad``."""
    c = grid.spec.centres()
    return np.all((c >= np.asarray(lo) - pad) & (c <= np.asarray(hi) + pad), axis=-1)


# ---------------------------------------------------------------------- the field against MuJoCo


def test_depth_images_the_world_simulates_give_mujocos_distance_to_the_block(seen):
    pos, size = block_of(seen)
    sc = with_sensors(seen, cameras_round(pos))
    world, problem = SimWorld(sc, 0), build_problem(sc)
    cut = SelfFilter(problem, padding=0.03)
    grid = VoxelGrid((-0.3, -0.45, 1.01), (0.5, 0.45, 1.4), CFG)
    for scan in readings(world):
        grid.insert(scan, cut(mirror(problem, world)))
    field = distance_field(grid.occupied(), grid.spec)
    assert field.dims == 3
    rng = np.random.default_rng(3)
    pts = pos + rng.uniform(-1, 1, (400, 3)) * (size + 0.15)
    pts = pts[(pts[:, 2] > 1.03) & (pts[:, 2] < 1.38)]  # in the box, off the table
    truth = mujoco_distance(pos, size, pts)
    out = truth > 0.0
    err = field.lookup(torch.as_tensor(pts[out])).numpy() - truth[out]
    # the surface lies somewhere in the voxels it crosses: within one of them, and on the
    # near side on average (a surface voxel reads -res/2 wherever in it the face is)
    assert np.abs(err).max() < RES, np.abs(err).max()
    assert err.max() < 0.5 * RES and err.mean() < 0.0
    assert (field.lookup(torch.as_tensor(pos[None])).numpy() < RES).all()


def test_a_block_moved_away_is_cleared_in_3d_after_the_clamps_scans(seen):
    pos, size = block_of(seen)
    world = SimWorld(seen, 0)
    grid = VoxelGrid((-0.3, -0.45, 1.01), (0.5, 0.45, 1.4), CFG)
    for _ in range(4):  # the seen faces held at l_max
        for scan in readings(world):
            grid.insert(scan)
    old = voxels_near(grid, pos - size, pos + size, RES / 2)
    seen_there = int((grid.occupied() & old).sum())
    assert seen_there >= 10
    elsewhere = pos + np.array([0.2, 0.25, 0.0])
    world.move_object("block", elsewhere)
    n = CFG.scans_to_clear()
    for i in range(n):
        assert (grid.occupied() & old).sum() == seen_there, f"cleared after {i} scans, not {n}"
        for scan in readings(world):
            grid.insert(scan)
    assert not (grid.occupied() & old).any()
    new = voxels_near(grid, elsewhere - size, elsewhere + size, RES / 2)
    assert (grid.occupied() & new).sum() >= 5
    field = distance_field(grid.occupied(), grid.spec)
    assert float(field.lookup(torch.as_tensor(pos[None]))) > 0.15


# --------------------------------------------------------------------------- known solids


def _geom_model(kind: str, size, pos, quat) -> tuple[mujoco.MjModel, mujoco.MjData]:
    xml = f"""
    <mujoco><worldbody>
      <geom type="{kind}" size="{" ".join(map(str, size))}" pos="{" ".join(map(str, pos))}"
            quat="{" ".join(map(str, quat))}"/>
      <body mocap="true"><geom type="sphere" size="0.0005"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return model, data


@pytest.mark.parametrize(
    "kind, size",
    [
        ("box", (0.1, 0.05, 0.2)),
        ("sphere", (0.1,)),
        ("capsule", (0.05, 0.15)),
        ("cylinder", (0.08, 0.1)),
    ],
)
def test_a_solids_distance_and_bounds_are_mujocos(kind, size):
    rng = np.random.default_rng(7)
    quat = rng.normal(size=4)
    quat /= np.linalg.norm(quat)
    pos = (0.1, -0.2, 0.3)
    model, data = _geom_model(kind, size, pos, quat)
    half = tuple(model.geom_size[0])
    solid = Solid(kind, half, pos, tuple(map(tuple, data.geom_xmat[0].reshape(3, 3))))
    pts = np.asarray(pos) + rng.uniform(-0.35, 0.35, (300, 3))
    got = solid.distance(pts)
    want = np.empty(len(pts))
    for i, p in enumerate(pts):
        data.mocap_pos[0] = p
        mujoco.mj_kinematics(model, data)
        want[i] = mujoco.mj_geomDistance(model, data, 1, 0, 10.0, None) + 0.0005
    outside = want > 1e-3  # MuJoCo's depth inside is its own convex penetration measure
    np.testing.assert_allclose(got[outside], want[outside], atol=2e-4)
    assert (got[~outside] <= 1e-3).all()
    # its bounding box holds it, tightly: the solid touches each of the box's faces
    lo, hi = solid.bounds()
    assert np.all(pts[got < 0] >= lo) and np.all(pts[got < 0] <= hi)
    u, v = np.meshgrid(np.linspace(0, 1, 150), np.linspace(0, 1, 150))
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        for level in (lo[axis], hi[axis]):
            face = np.empty((u.size, 3))
            face[:, axis] = level
            face[:, a] = lo[a] + u.ravel() * (hi[a] - lo[a])
            face[:, b] = lo[b] + v.ravel() * (hi[b] - lo[b])
            d = solid.distance(face)
            assert d.min() > -1e-9 and d.min() < 3e-3, (axis, level, d.min())


def test_solids_on_a_grid_are_their_distance_at_the_cell_centres():
    spec = GridSpec.box((-0.5, -0.5, 0.0), (0.5, 0.5, 0.6), 0.05)
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    solids = [
        Solid("box", (0.1, 0.1, 0.1), (0.2, 0.0, 0.1), eye),
        Solid("sphere", (0.1, 0, 0), (-0.2, 0.1, 0.4), eye),
    ]
    field = solid_field(solids, spec)
    c = spec.centres().reshape(-1, 3)
    want = np.minimum(solids[0].distance(c), solids[1].distance(c)).reshape(spec.shape)
    np.testing.assert_allclose(field.values.numpy(), want)
    with pytest.raises(ValueError, match="3-D"):
        solid_field(solids, GridSpec.box((0.0, 0.0), (1.0, 1.0), 0.1))


# ---------------------------------------------------------------------------- the self-filter


def test_a_ray_ends_where_it_enters_a_sphere_and_loses_its_return():
    dirs = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    rays = Rays(
        np.zeros(3), dirs, np.array([3.0, 0.5, 3.0, 3.0]), np.array([True, True, False, True])
    )
    spheres = np.array([[1.0, 0.0, 0.0, 0.2], [0.0, 2.0, 0.0, 0.5]])
    out = clip_rays(rays, spheres)
    # through the first sphere: ends at 0.8, no return; the one whose return is nearer keeps
    # it; the miss ends at the second sphere; the ray away from both is left as it was
    np.testing.assert_allclose(out.ends, [0.8, 0.5, 1.5, 3.0])
    assert out.hit.tolist() == [False, True, False, True]
    inside = clip_rays(rays, np.array([[0.0, 0.0, 0.0, 0.1]]))  # the sensor inside one
    assert np.all(inside.ends == 0.0) and not inside.hit.any()
    assert clip_rays(rays, np.zeros((0, 4))) is rays


def test_a_cube_in_view_is_not_an_obstacle_with_the_self_filter(seen):
    world, problem = SimWorld(seen, 0), build_problem(seen)
    cut = SelfFilter(problem, padding=0.03)
    cube = problem.model.body("cube_a")
    adr = problem.model.jnt_qposadr[cube.jntadr[0]]
    held = np.array([0.0, -0.1, 1.25])  # in mid-air in front of the camera, as if carried
    world.data.qpos[adr : adr + 3] = held
    mujoco.mj_kinematics(world.model, world.data)
    plain, filtered = (VoxelGrid((-0.3, -0.45, 1.01), (0.5, 0.45, 1.4), CFG) for _ in range(2))
    scene = mirror(problem, world)
    for scan in readings(world):
        plain.insert(scan)
        filtered.insert(scan, cut(scene))
    there = voxels_near(plain, held - 0.025, held + 0.025, RES)
    assert (plain.occupied() & there).sum() >= 3  # unfiltered, the cube is an obstacle
    assert not (filtered.occupied() & there).any()
    spheres = cut(scene)
    centres = filtered.spec.centres()[filtered.occupied()]
    gaps = np.linalg.norm(centres[:, None] - spheres[None, :, :3], axis=-1) - spheres[:, 3]
    assert gaps.min() > -RES  # nothing of the robot or the cubes in the map
    pos, size = block_of(seen)
    assert (filtered.occupied() & voxels_near(filtered, pos - size, pos + size, RES / 2)).any()


def test_the_arm_in_front_of_the_block_does_not_clear_it(seen):
    # a camera straight above the hand, the block moved under it: with the arm swung aside the
    # camera sees the block; back over it, the hand hides part of it. The world writes no return
    # for a ray that meets the robot, which read as is would say "free to range_max"
    hand = np.array([-0.143, 0.0])
    cam = DepthConfig(name="top", pos=(*hand, 2.3), look_at=(*hand, 1.0), range=(0.1, 3.0))
    sc = with_sensors(seen, [cam])
    world, problem = SimWorld(sc, 0), build_problem(sc)
    _, size = block_of(seen)
    pos = np.array([*hand, 1.035])
    world.move_object("block", pos)
    start = world.data.qpos[0]
    cut = SelfFilter(problem, padding=0.03)
    plain, filtered = (VoxelGrid((-0.35, -0.2, 1.01), (0.05, 0.2, 1.3), CFG) for _ in range(2))
    block = voxels_near(plain, pos - size, pos + size, RES / 2)

    def look(n: int) -> None:
        mujoco.mj_kinematics(world.model, world.data)
        scene = mirror(problem, world)
        for _ in range(n):
            for scan in readings(world):
                plain.insert(scan)
                filtered.insert(scan, cut(scene))

    world.data.qpos[0] = start + 1.5  # joint 1: the arm swung aside
    look(3)
    before = int((filtered.occupied() & block).sum())
    assert before >= 6 and before == (plain.occupied() & block).sum()
    world.data.qpos[0] = start  # the hand over the block again
    look(CFG.scans_to_clear() + 2)
    assert (filtered.occupied() & block).sum() == before
    assert (plain.occupied() & block).sum() < before  # what the filter prevents
