"""The browser view's drawing: a compiled model's geoms as meshes (every type the shipped
scenarios use, and meshes), their world poses and colours; the trajectories' colours by mode.
Pure functions, no browser and no viser needed."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from m3p2i.view import MODE_COLOURS, path_segments, trajectory_segments, weight_bar
from m3p2i.view_scene import (
    box_mesh,
    camera_for,
    capsule_mesh,
    cylinder_mesh,
    geom_poses,
    scene_bounds,
    scene_shapes,
    sphere_mesh,
)
from shared.scenario import load_scenario
from shared.scene import compile_model, initial_data

SCENARIOS = sorted(
    p.stem for p in (Path(__file__).parents[2] / "configs" / "scenarios").glob("*.yaml")
)


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Volume enclosed by a closed triangle mesh; positive when its faces wind outwards."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


@pytest.mark.parametrize("name", SCENARIOS)
def test_every_geom_of_every_shipped_scenario_is_drawn(name):
    model = compile_model(load_scenario(name))
    shapes = scene_shapes(model)
    # every shipped geom is visible (groups 0-2): none may be missing from the page
    assert [s.geom_id for s in shapes] == list(range(model.ngeom))
    for s in shapes:
        assert s.vertices.dtype == np.float32 and s.vertices.shape[1] == 3
        assert s.faces.dtype == np.uint32 and s.faces.max() < len(s.vertices)
        assert np.all(np.isfinite(s.vertices))


def test_the_shipped_scenarios_use_these_geom_types():
    # if a scenario starts using another type, the tests below must cover it
    kinds = {s.kind for n in SCENARIOS for s in scene_shapes(compile_model(load_scenario(n)))}
    assert kinds == {"plane", "box", "cylinder", "capsule"}


@pytest.mark.parametrize(
    "mesh, volume, extent",
    [
        (box_mesh(np.array([0.1, 0.2, 0.3])), 0.2 * 0.4 * 0.6, [0.1, 0.2, 0.3]),
        (cylinder_mesh(0.1, 0.25), np.pi * 0.1**2 * 0.5, [0.1, 0.1, 0.25]),
        (capsule_mesh(0.1, 0.25), np.pi * 0.1**2 * 0.5 + 4 / 3 * np.pi * 0.1**3, [0.1, 0.1, 0.35]),
        (sphere_mesh(0.2), 4 / 3 * np.pi * 0.2**3, [0.2, 0.2, 0.2]),
    ],
    ids=["box", "cylinder", "capsule", "sphere"],
)
def test_primitives_are_closed_outward_meshes_of_mujocos_size(mesh, volume, extent):
    v, f = mesh
    np.testing.assert_allclose(np.abs(v).max(0), extent, rtol=1e-6)
    # outward winding (lit from outside in the browser) and the right size: within the 24-gon's
    # inscribed area loss (about 2 %)
    assert _signed_volume(v, f) == pytest.approx(volume, rel=0.04)


def test_a_geom_drawn_at_its_pose_is_where_mujoco_has_it():
    """Vertices put through the published pose land on MuJoCo's own surface (a tilted capsule
    on a hinged body: its tip, and a box's corner)."""
    xml = """<mujoco><worldbody>
      <body name="arm" pos="0.3 -0.2 0.5" euler="10 20 30"><joint type="hinge" axis="0 1 0"/>
        <geom name="link" type="capsule" fromto="0 0 0 0.4 0 0.1" size="0.03"/>
        <geom name="plate" type="box" size="0.1 0.05 0.02" pos="0 0.2 0" euler="0 0 45"
              rgba="1 0 0 1"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qpos[0] = 0.7
    mujoco.mj_forward(model, data)
    pos, quat = geom_poses(model, data)
    shapes = {s.name: s for s in scene_shapes(model)}
    for name in ("link", "plate"):
        g = shapes[name].geom_id
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, quat[g])
        world = shapes[name].vertices @ rot.reshape(3, 3).T + pos[g]
        expected = shapes[name].vertices @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        np.testing.assert_allclose(world, expected, atol=1e-6)
    # the capsule's poles: fromto's end points pushed out by the radius along the axis
    g = shapes["link"].geom_id
    start = data.xpos[1]
    tip = data.xpos[1] + data.xmat[1].reshape(3, 3) @ np.array([0.4, 0, 0.1])
    direction = (tip - start) / np.linalg.norm(tip - start)
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, quat[g])
    world = shapes["link"].vertices @ rot.reshape(3, 3).T + pos[g]
    along = world @ direction
    np.testing.assert_allclose(world[np.argmax(along)], tip + 0.03 * direction, atol=1e-6)
    np.testing.assert_allclose(world[np.argmin(along)], start - 0.03 * direction, atol=1e-6)


def test_a_mesh_geom_is_drawn_with_its_own_vertices_and_material_colour():
    xml = """<mujoco><asset>
        <mesh name="tet" vertex="0 0 0  0.2 0 0  0 0.2 0  0 0 0.2"/>
        <material name="blue" rgba="0 0 1 1"/>
      </asset><worldbody><body pos="1 2 3"><freejoint/>
        <geom name="tet" type="mesh" mesh="tet" material="blue"/></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    (shape,) = scene_shapes(model)
    assert shape.kind == "mesh" and len(shape.faces) == 4 and shape.movable
    assert shape.rgba == (0.0, 0.0, 1.0, 1.0)  # the material's: the geom kept the default
    pos, quat = geom_poses(model, data)
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, quat[0])
    world = shape.vertices @ rot.reshape(3, 3).T + pos[0]
    # MuJoCo recentres a mesh at its centroid; through the pose the corners are where they were
    expected = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.2]]) + [1, 2, 3]
    np.testing.assert_allclose(np.sort(world, axis=0), np.sort(expected, axis=0), atol=1e-5)


def test_pick_place_colours_and_what_moves():
    sc = load_scenario("pick_place")
    model = compile_model(sc)
    shapes = {s.name: s for s in scene_shapes(model)}
    rgba = {o.name: tuple(o.rgba) for o in sc.world.objects}
    for name in ("cube_a", "cube_b"):
        assert shapes[name].rgba == pytest.approx(rgba[name])
        assert shapes[name].movable  # free objects
    assert shapes["link1"].movable and shapes["finger_left"].movable  # the arm
    assert shapes["link1"].rgba == pytest.approx((0.95, 0.95, 0.95, 1.0))
    assert not shapes["floor"].movable and not shapes["mount"].movable  # never re-sent
    assert shapes["floor"].kind == "plane"


def test_a_mocap_obstacle_is_movable_and_a_wall_is_not():
    sc = load_scenario("push_dynamic_obstacle")
    shapes = {s.name: s for s in scene_shapes(compile_model(sc))}
    mocap = [o.name for o in sc.world.objects if o.fixed]
    assert mocap and all(shapes[n].movable for n in mocap)
    assert not shapes["wall_north"].movable


@pytest.mark.parametrize("name", ["pick_place", "push_pull_corner2"])
def test_the_camera_frames_the_scene(name):
    sc = load_scenario(name)
    model = compile_model(sc)
    data = initial_data(sc, model)
    lo, hi = scene_bounds(model, data, scene_shapes(model))
    position, look_at = camera_for(lo, hi)
    assert np.all(look_at >= lo) and np.all(look_at <= hi)
    distance = np.linalg.norm(position - look_at)
    radius = np.linalg.norm(hi - lo) / 2
    # the whole scene within the page's 75° field of view (R / sin 37.5° = 1.64 R), not lost
    # in the distance
    assert 1.64 * radius < distance < 3 * radius
    assert position[2] > look_at[2]  # from above


def test_trajectories_are_coloured_by_their_mode():
    top = np.zeros((3, 4, 3))
    top[:, :, 0] = np.arange(4)
    segs, cols = trajectory_segments(top, np.array([0, 1, 1]))
    assert segs.shape == (9, 2, 3) and cols.shape == (9, 2, 3)
    np.testing.assert_array_equal(segs[0], [[0, 0, 0], [1, 0, 0]])
    assert tuple(cols[0, 0]) == MODE_COLOURS[0]
    assert tuple(cols[3, 0]) == MODE_COLOURS[1] and tuple(cols[8, 1]) == MODE_COLOURS[1]
    assert trajectory_segments(np.zeros((0, 0, 3)), None)[0].shape == (0, 2, 3)
    assert path_segments(np.arange(9.0).reshape(3, 3)).shape == (2, 2, 3)


def test_weight_bar():
    assert weight_bar(0.25, width=8) == "██░░░░░░"
    assert weight_bar(1.7, width=4) == "████" and weight_bar(-1, width=4) == "░░░░"


def test_the_arena_walls_are_drawn_along_the_walls_and_as_tall_as_configured():
    sc = load_scenario("push_pull_corner2")
    model = compile_model(sc)
    data = initial_data(sc, model)
    h, z = sc.world.arena.half_size, sc.world.arena.wall_height
    for s in scene_shapes(model):
        if not s.name.startswith("wall_"):
            continue
        world = s.vertices @ data.geom_xmat[s.geom_id].reshape(3, 3).T + data.geom_xpos[s.geom_id]
        np.testing.assert_allclose(world[:, 2].min(), 0.0, atol=1e-6)  # from the floor
        np.testing.assert_allclose(world[:, 2].max(), 2 * z, atol=1e-6)  # up to 2 x wall_height
        span = np.ptp(world[:, :2], axis=0)
        np.testing.assert_allclose(sorted(span), [0.0, 2 * h], atol=1e-6)  # the arena's side
