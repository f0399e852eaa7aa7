"""The planner's map (planner_client/perception): lidar scans and depth images cast by MuJoCo
itself (``mj_multiRay``) into a scene with a box and a cylinder, fused into occupancy and turned
into a signed distance field that matches MuJoCo's own distance (``mj_geomDistance``) at random
points; an obstacle that moved away cleared after the scans the map's clamp allows; the known
geometry composed in; the updater's thread publishing and closing, and lock-step repeatable."""

from __future__ import annotations

import math
import threading
import time

import mujoco
import numpy as np
import pytest
import torch
from scipy.ndimage import distance_transform_edt

from planner_client.global_path import Shape, signed_distance
from planner_client.perception.grid import GridSpec
from planner_client.perception.grid2d import OccupancyGrid2D
from planner_client.perception.occupancy import MapConfig
from planner_client.perception.raycast import crossed
from planner_client.perception.rays import world_rays
from planner_client.perception.sdf import compose, distance_field, far, known_field
from planner_client.perception.updater import MapUpdater
from planner_client.perception.voxels import VoxelGrid
from shared.scans import Scan

SCENE = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="box" mocap="true" pos="0.9 0.5 0.3" euler="0 0 23">
      <geom name="box" type="box" size="0.3 0.2 0.3"/>
    </body>
    <body name="cyl" pos="-0.7 -0.6 0.3">
      <geom name="cyl" type="cylinder" size="0.25 0.3"/>
    </body>
    <body name="probe" mocap="true">
      <geom name="probe" type="sphere" size="0.001" group="3" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
</mujoco>
"""
PROBE_R = 0.001
RAY_GROUPS = np.array([1, 1, 1, 0, 1, 1], dtype=np.uint8)  # the probe (group 3) casts no shadow
LIDAR_POSES = [(-1.8, 1.6, -0.6), (2.0, -1.5, 2.4), (2.1, 1.9, -2.3), (-1.9, -1.9, 0.8), (0, 0, 0)]


@pytest.fixture
def scene() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def cast(model, data, scan: Scan) -> Scan:
    """``scan`` with its ranges measured by MuJoCo (no hit: 0, below range_min, no return)."""
    origin, dirs = world_rays(scan)
    n = dirs.shape[0]
    geomid, dist = np.zeros(n, np.int32), np.zeros(n)
    mujoco.mj_multiRay(
        model, data, origin, dirs.reshape(-1), RAY_GROUPS, 1, -1, geomid, dist, None, n, 100.0
    )
    scan.ranges = np.where(dist < 0, 0.0, dist).reshape(scan.ranges.shape)
    return scan


def lidar(model, data, x: float, y: float, yaw: float, t: float = 0.0, n: int = 720) -> Scan:
    quat = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    pos, step = np.array([x, y, 0.2]), 2 * math.pi / n
    scan = Scan("base_lidar", "lidar", t, pos, quat, np.zeros(n), 0.05, 6.0, -math.pi, step)
    return cast(model, data, scan)


def depth(model, data, pos, target, size=(72, 96), t: float = 0.0) -> Scan:
    """A depth camera at ``pos`` looking at ``target`` (image y down, OpenCV's convention)."""
    z = np.subtract(target, pos) / np.linalg.norm(np.subtract(target, pos))
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([x, np.cross(z, x), z], axis=1).reshape(-1))
    pos = np.asarray(pos, float)
    scan = Scan("cam", "depth", t, pos, quat, np.zeros(size), 0.05, 5.0, fovy=60.0)
    return cast(model, data, scan)


def true_distance(model, data, points: np.ndarray) -> np.ndarray:
    """MuJoCo's distance ``[N]`` from each point to the box and the cylinder (a tiny probe)."""
    probe = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "probe")
    geoms = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in ("box", "cyl")]
    out = np.empty(len(points))
    for i, p in enumerate(points):
        data.mocap_pos[1] = p
        mujoco.mj_kinematics(model, data)
        out[i] = min(mujoco.mj_geomDistance(model, data, probe, g, 10.0, None) for g in geoms)
    return out + PROBE_R


def move_box(model, data, xy) -> None:
    data.mocap_pos[0][:2] = xy
    mujoco.mj_forward(model, data)


# ------------------------------------------------------------------------------- ray stepping


def test_rays_mark_the_cells_they_cross_inside_the_grid():
    spec = GridSpec((0.5, 0.5), 1.0, (10, 10))  # cells of 1 m over [0, 10]^2
    along = crossed(spec, np.array([-5.0, 2.5]), np.array([[1.0, 0.0]]), np.array([9.0]))
    assert np.flatnonzero(along).tolist() == [20, 21, 22, 23]  # row 2, x in [0, 4)
    missing = crossed(spec, np.array([-5.0, 12.5]), np.array([[1.0, 0.0]]), np.array([50.0]))
    assert not missing.any()
    diagonal = np.array([[1.0, 1.0]]) / math.sqrt(2)
    cells = crossed(spec, np.array([0.2, 0.1]), diagonal, np.array([20.0])).reshape(10, 10)
    assert np.all(np.diag(cells)) and cells.sum() <= 28  # the diagonal and its neighbours
    with pytest.raises(ValueError, match="a side"):
        GridSpec((0.0, 0.0), 0.01, (10, 9000))


# ------------------------------------------------------------------------------------ the field


def test_lidar_field_matches_mujocos_distance(scene):
    model, data = scene
    cfg = MapConfig(resolution=0.05)
    grid = OccupancyGrid2D.arena(2.5, 0.2, cfg)
    for x, y, yaw in LIDAR_POSES:
        grid.insert(lidar(model, data, x, y, yaw))
    field = distance_field(grid.occupied(), grid.spec, grid.time)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-2.4, 2.4, (400, 2)), np.full(400, 0.2)])
    truth = true_distance(model, data, pts)
    out = truth > 0.0
    err = field.lookup(torch.as_tensor(pts[out])).numpy() - truth[out]
    assert np.abs(err).max() < 1.5 * cfg.resolution, np.abs(err).max()
    # an occupied cell stands for all of it: the field errs on the near side, by half a cell
    # on average (the surface lies anywhere in the cells it crosses)
    assert err.max() < 0.25 * cfg.resolution
    assert err.mean() == pytest.approx(-0.5 * cfg.resolution, abs=0.25 * cfg.resolution)


def test_depth_images_into_voxels_match_mujocos_distance(scene):
    model, data = scene
    cfg = MapConfig(resolution=0.05)
    # above the floor: the cameras see it, and it is not an obstacle the test measures
    vox = VoxelGrid((-1.4, -1.3, 0.06), (1.6, 1.3, 0.96), cfg)
    for a in np.linspace(0.3, 2 * math.pi + 0.3, 5)[:-1]:
        pos = (2.6 * math.cos(a), 2.6 * math.sin(a), 1.5)
        vox.insert(depth(model, data, pos, (0.1, 0.0, 0.3)))
    field = distance_field(vox.occupied(), vox.spec, vox.time)
    assert field.values.shape == vox.spec.shape
    rng = np.random.default_rng(1)
    pts = np.column_stack(
        [rng.uniform(-1.3, 1.5, 300), rng.uniform(-1.2, 1.2, 300), rng.uniform(0.15, 0.9, 300)]
    )
    truth = true_distance(model, data, pts)
    out = truth > 0.0
    err = field.lookup(torch.as_tensor(pts[out])).numpy() - truth[out]
    assert np.abs(err).max() < 1.5 * cfg.resolution, np.abs(err).max()
    assert err.max() < 0.5 * cfg.resolution  # the near side, as in 2-D


def test_an_obstacle_moved_away_is_cleared_after_the_clamps_scans(scene):
    model, data = scene
    cfg = MapConfig(resolution=0.05)
    grid = OccupancyGrid2D.arena(2.5, 0.2, cfg)
    pose = (-1.8, 1.6, -0.6)
    for _ in range(4):  # the box's cells held at l_max
        grid.insert(lidar(model, data, *pose))
    near = np.linalg.norm(grid.spec.centres() - (0.9, 0.5), axis=-1) < 0.45  # the box's place
    seen = int((grid.occupied() & near).sum())
    assert seen > 5 and np.all(grid.logodds[grid.occupied()] == np.float32(cfg.l_max))
    move_box(model, data, (0.0, -2.3))  # a person walks away: to the south edge
    n = cfg.scans_to_clear()
    assert n == 5
    for i in range(n):
        assert (grid.occupied() & near).sum() == seen, f"cleared after {i} scans, not {n}"
        grid.insert(lidar(model, data, *pose))
    assert not (grid.occupied() & near).any()
    field = distance_field(grid.occupied(), grid.spec)
    # the cylinder remains, 1.69 m from where the box stood, and the box 2.4 m off
    assert float(field.lookup(torch.tensor([[0.9, 0.5]]))) > 1.6
    assert float(field.lookup(torch.tensor([[-0.7, -0.6]]))) < 0.3


def test_a_planar_map_reads_rays_near_its_plane_only(scene):
    model, data = scene
    cfg = MapConfig(resolution=0.05, max_tilt=0.05)
    level, pitched = OccupancyGrid2D.arena(2.5, 0.2, cfg), OccupancyGrid2D.arena(2.5, 0.2, cfg)
    level.insert(lidar(model, data, -1.8, 1.6, -0.6))
    scan = lidar(model, data, -1.8, 1.6, -0.6)
    tilt = 0.2  # pitched about its y axis: its rays slope to the floor, but those along ±y
    scan.quat = np.array([math.cos(tilt / 2), 0.0, math.sin(tilt / 2), 0.0])
    pitched.insert(scan)
    # rays within max_tilt of the plane: those within asin(sin 0.05 / sin 0.2) of ±y, 16 %
    share = 4 * math.asin(math.sin(cfg.max_tilt) / math.sin(tilt)) / (2 * math.pi)
    assert pitched.scans == 1 and share == pytest.approx(0.16, abs=0.01)
    ratio = (pitched.logodds != 0).sum() / (level.logodds != 0).sum()
    assert 0.5 * share < ratio < 1.5 * share
    with pytest.raises(ValueError, match="does not read depth"):
        level.insert(depth(model, data, (2.0, 0.0, 1.0), (0.0, 0.0, 0.3), size=(6, 8)))


# ------------------------------------------------------------------------- SDF and composition


def test_sdf_of_one_cell_and_of_nothing():
    spec = GridSpec((0.0, 0.0), 0.1, (5, 7))
    occ = np.zeros(spec.shape, bool)
    f = distance_field(occ, spec)
    assert torch.all(f.values == far(spec)) and far(spec) == pytest.approx(math.hypot(0.7, 0.5))
    occ[2, 3] = True
    v = distance_field(occ, spec, time=1.5).values.numpy()
    assert v[2, 3] == pytest.approx(-0.05) and v[2, 4] == pytest.approx(0.05)
    assert v[0, 0] == pytest.approx(math.hypot(0.3, 0.2) - 0.05)
    assert distance_field(occ, spec, time=1.5).time == 1.5
    with pytest.raises(ValueError, match="does not match"):
        distance_field(occ.T, spec)


@pytest.mark.parametrize("shape", [(40, 50), (12, 14, 16)])
def test_sdf_is_the_exact_transform_both_ways(shape):
    """The inside is transformed round the occupied cells only: the same as over the grid."""
    rng = np.random.default_rng(2)
    occ = np.zeros(shape, bool)
    occ[tuple(slice(3, n // 2) for n in shape)] = rng.random([n // 2 - 3 for n in shape]) < 0.7
    spec = GridSpec((0.0,) * len(shape), 0.1, shape)
    want = np.where(
        occ,
        0.05 - distance_transform_edt(occ, sampling=0.1),
        distance_transform_edt(~occ, sampling=0.1) - 0.05,
    )
    np.testing.assert_allclose(distance_field(occ, spec).values.numpy(), want, atol=1e-12)


def test_known_shapes_rasterised_and_composed():
    spec = GridSpec.box((-2.0, -2.0), (2.0, 2.0), 0.1)
    shapes = [Shape("box", (0.5, 0.0), (0.3, 0.2), 0.3), Shape("halfplane", (-1.5, 0), yaw=0.0)]
    known = known_field(shapes, spec)
    centres = spec.centres().reshape(-1, 2)
    np.testing.assert_allclose(
        known.values.numpy().reshape(-1), signed_distance(shapes, centres), atol=1e-12
    )
    occ = np.zeros(spec.shape, bool)
    occ[30, 10] = True  # a seen obstacle at (-1.0, 1.0)
    seen = distance_field(occ, spec, time=2.0)
    both = compose(seen, known)
    assert torch.equal(both.values, torch.minimum(seen.values, known.values))
    assert both.time == 2.0
    with pytest.raises(ValueError, match="one grid"):
        compose(both, known_field(shapes, GridSpec.box((-2.0, -2.0), (2.0, 2.0), 0.2)))


def test_known_shapes_extruded_in_3d():
    spec = GridSpec.box((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0), 0.1)
    f = known_field([Shape("disk", (0.0, 0.0), (0.3, 0.0))], spec, z=(0.0, 0.5))
    pts = torch.tensor([[0.75, 0.05, 0.25], [0.05, 0.05, 0.85], [0.65, 0.05, 0.75]], dtype=float)
    want = [0.75 - 0.3, 0.85 - 0.5, math.hypot(0.35, 0.25)]
    np.testing.assert_allclose(f.lookup(pts).numpy(), want, atol=0.01)
    with pytest.raises(ValueError, match="extrudes"):
        known_field([], spec)


# ---------------------------------------------------------------------------------- the updater


def scans(model, data) -> list[Scan]:
    return [lidar(model, data, x, y, yaw, t=0.1 * i) for i, (x, y, yaw) in enumerate(LIDAR_POSES)]


def test_lock_step_updates_are_repeatable_and_composed(scene):
    model, data = scene
    batch = scans(model, data)
    cfg = MapConfig(resolution=0.05)
    walls = OccupancyGrid2D.arena(2.5, 0.2, cfg).spec
    known = known_field([Shape("halfplane", (0.0, -2.5), yaw=math.pi / 2)], walls)
    fields = []
    for _ in range(2):
        up = MapUpdater(OccupancyGrid2D.arena(2.5, 0.2, cfg), known=known)
        assert up.latest() is None
        for i in range(0, len(batch), 2):
            up.submit(batch[i : i + 2])
            fields.append(up.update_now())
        up.close()
    half = len(fields) // 2
    for a, b in zip(fields[:half], fields[half:]):
        assert torch.equal(a.values, b.values) and a.time == b.time
    last = fields[half - 1]
    assert last.time == pytest.approx(0.4)
    assert float(last.lookup(torch.tensor([[0.0, -2.6]]))) < 0.0  # beyond the known wall
    stats = up.stats()
    assert stats["fused"] == len(batch) and stats["fields"] == 3 and stats["update_s"] > 0


def test_updater_reads_its_sensors_and_drops_the_oldest(scene):
    model, data = scene
    batch = scans(model, data)
    cfg = MapConfig(resolution=0.05, max_queue=3)
    up = MapUpdater(OccupancyGrid2D.arena(2.5, 0.2, cfg), sensors=["base_lidar"])
    other = lidar(model, data, 0.0, 0.0, 0.0)
    other.name = "other_lidar"
    up.submit([*batch, other])
    field = up.update_now()
    stats = up.stats()
    assert (stats["submitted"], stats["dropped"], stats["ignored"]) == (5, 2, 1)
    assert stats["fused"] == 3 and field.time == pytest.approx(0.4)
    up.close()


def test_updater_thread_publishes_at_its_rate_and_closes(scene):
    model, data = scene
    cfg = MapConfig(resolution=0.05, rate_hz=50.0)
    up = MapUpdater(OccupancyGrid2D.arena(2.5, 0.2, cfg), threaded=True)
    try:
        for scan in scans(model, data):
            up.submit([scan])
            time.sleep(0.01)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            f = up.latest()
            if f is not None and f.time == pytest.approx(0.4):
                break
            time.sleep(0.01)
        assert f is not None and f.time == pytest.approx(0.4)
        stats = up.stats()
        assert stats["fused"] == 5 and 1 <= stats["fields"] <= 5
        assert stats["field_s"] > 0 and stats["fuse_s"] > 0
    finally:
        up.close()
    assert not any(t.name == "map-updater" for t in threading.enumerate())
