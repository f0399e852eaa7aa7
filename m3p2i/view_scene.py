"""A compiled MuJoCo model as triangle meshes for a browser: what ``m3p2i view`` draws.

Pure functions, no viewer library: :func:`scene_shapes` turns every visible geom of the model
(primitives and meshes alike) into a mesh in the geom's own frame with its colour, and
:func:`geom_poses` gives each geom's world pose for one ``MjData``. The view sends the meshes
once and only the poses of the geoms that can move afterwards, so a frame costs a few numbers
per moving geom whatever the meshes' size.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

_T = mujoco.mjtGeom
VISIBLE_GROUPS = (0, 1, 2)
"""Geom groups drawn, as MuJoCo's own viewer does by default (3-5 hold collision-only shapes)."""
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)  # MuJoCo's geom rgba when none is given: take the material's
_SEGMENTS = 24  # around a cylinder, capsule or sphere: smooth enough at 1 m


@dataclass(frozen=True)
class GeomShape:
    """One geom as a mesh in its own frame: ``vertices [V, 3]`` (float32, metres),
    ``faces [F, 3]`` (uint32, counter-clockwise seen from outside), ``rgba`` in 0-1, and
    whether its pose can change during an episode (a body with joints, or a mocap body)."""

    geom_id: int
    name: str
    kind: str  # box | sphere | capsule | cylinder | ellipsoid | plane | mesh
    vertices: np.ndarray
    faces: np.ndarray
    rgba: tuple[float, float, float, float]
    movable: bool


def box_mesh(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box of half-sizes ``half [3]`` centred at the origin."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],  # -x, +x
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],  # -y, +y
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )  # -z, +z
    return corners * np.asarray(half, float), faces


def _lathe(profile: np.ndarray, segments: int = _SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """A surface of revolution about z from ``profile [P, 2]`` of (radius, z), bottom to top;
    a radius of 0 at either end closes it with a single pole vertex."""
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    rings, faces = [], []
    for r, z in profile:
        rings.append(np.stack([r * np.cos(angles), r * np.sin(angles), np.full(segments, z)], 1))
    verts = np.concatenate(rings)
    for i in range(len(profile) - 1):
        a, b = i * segments, (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            faces += [[a + j, a + k, b + k], [a + j, b + k, b + j]]
    faces = np.array(faces)
    # caps: a flat end (radius > 0) gets a centre vertex; degenerate triangles at poles are harmless
    extra = []
    for ring, z, up in ((0, profile[0][1], False), (len(profile) - 1, profile[-1][1], True)):
        if profile[ring][0] > 0:
            centre = len(verts) + len(extra)
            extra.append([0.0, 0.0, z])
            a = ring * segments
            for j in range(segments):
                k = (j + 1) % segments
                faces = np.vstack([faces, [centre, a + j, a + k] if up else [centre, a + k, a + j]])
    if extra:
        verts = np.vstack([verts, extra])
    return verts, faces


def sphere_mesh(radius: float, segments: int = _SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    theta = np.linspace(-np.pi / 2, np.pi / 2, segments // 2 + 1)
    return _lathe(np.stack([radius * np.cos(theta), radius * np.sin(theta)], 1), segments)


def cylinder_mesh(radius: float, half_length: float, segments: int = _SEGMENTS):
    return _lathe(np.array([[radius, -half_length], [radius, half_length]]), segments)


def capsule_mesh(radius: float, half_length: float, segments: int = _SEGMENTS):
    theta = np.linspace(-np.pi / 2, 0, segments // 4 + 1)
    low = np.stack([radius * np.cos(theta), radius * np.sin(theta) - half_length], 1)
    up = np.linspace(0, np.pi / 2, segments // 4 + 1)
    high = np.stack([radius * np.cos(up), radius * np.sin(up) + half_length], 1)
    return _lathe(np.vstack([low, high]), segments)


def plane_mesh(half_x: float, half_y: float) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle in the plane's xy facing +z (the viewer draws its back too). MuJoCo draws
    an infinite plane (size 0) as a large one; so does this (10 m)."""
    hx, hy = half_x or 10.0, half_y or 10.0
    verts = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], float)
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def geom_mesh(model: mujoco.MjModel, g: int) -> tuple[str, np.ndarray, np.ndarray]:
    """``(kind, vertices, faces)`` of geom ``g`` in its own frame; ValueError for a type that
    has no surface to draw (heightfields, SDFs), naming the geom."""
    kind, size = int(model.geom_type[g]), model.geom_size[g]
    if kind == _T.mjGEOM_BOX:
        return ("box", *box_mesh(size))
    if kind == _T.mjGEOM_SPHERE:
        return ("sphere", *sphere_mesh(size[0]))
    if kind == _T.mjGEOM_ELLIPSOID:
        v, f = sphere_mesh(1.0)
        return "ellipsoid", v * size, f
    if kind == _T.mjGEOM_CYLINDER:
        return ("cylinder", *cylinder_mesh(size[0], size[1]))
    if kind == _T.mjGEOM_CAPSULE:
        return ("capsule", *capsule_mesh(size[0], size[1]))
    if kind == _T.mjGEOM_PLANE:
        return ("plane", *plane_mesh(size[0], size[1]))
    if kind == _T.mjGEOM_MESH:
        m = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        f0, nf = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        # the compiled mesh is already in the geom's frame (MuJoCo moved it to its inertial frame
        # and set geom_pos/quat accordingly)
        return "mesh", model.mesh_vert[v0 : v0 + nv].copy(), model.mesh_face[f0 : f0 + nf].copy()
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
    raise ValueError(f"geom {name!r}: type {_T(kind).name} cannot be drawn in the view")


def geom_rgba(model: mujoco.MjModel, g: int) -> tuple[float, float, float, float]:
    """The geom's colour: its own rgba, or its material's when the geom kept MuJoCo's default."""
    rgba = tuple(float(c) for c in model.geom_rgba[g])
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(rgba, _DEFAULT_RGBA):
        rgba = tuple(float(c) for c in model.mat_rgba[mat])
    return rgba


def _movable_bodies(model: mujoco.MjModel) -> np.ndarray:
    """[nbody] bool: bodies whose pose can change (joints on the way to the world, or mocap)."""
    moving = np.zeros(model.nbody, bool)
    for b in range(1, model.nbody):
        parent = int(model.body_parentid[b])
        moving[b] = moving[parent] or model.body_jntnum[b] > 0 or model.body_mocapid[b] >= 0
    return moving


def scene_shapes(model: mujoco.MjModel) -> list[GeomShape]:
    """Every visible geom of ``model`` (groups 0-2, alpha > 0) as a :class:`GeomShape`."""
    moving = _movable_bodies(model)
    shapes = []
    for g in range(model.ngeom):
        rgba = geom_rgba(model, g)
        if int(model.geom_group[g]) not in VISIBLE_GROUPS or rgba[3] <= 0:
            continue
        kind, verts, faces = geom_mesh(model, g)
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
        shapes.append(
            GeomShape(
                geom_id=g,
                name=name,
                kind=kind,
                vertices=np.asarray(verts, np.float32),
                faces=np.asarray(faces, np.uint32),
                rgba=rgba,
                movable=bool(moving[int(model.geom_bodyid[g])]),
            )
        )
    return shapes


def geom_poses(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """World poses of all geoms after kinematics: positions ``[ngeom, 3]`` and quaternions
    ``[ngeom, 4]`` (w, x, y, z)."""
    quats = np.empty((model.ngeom, 4))
    for g in range(model.ngeom):
        mujoco.mju_mat2Quat(quats[g], data.geom_xmat[g])
    return data.geom_xpos.copy(), quats


def scene_bounds(
    model: mujoco.MjModel, data: mujoco.MjData, shapes: list[GeomShape]
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners ``[3]`` of what is worth framing: every drawn geom but the
    ground (a plane facing up: a floor would frame 10 m of nothing around a table); an arena's
    walls count."""
    points = []
    for s in shapes:
        if s.kind == "plane" and data.geom_xmat[s.geom_id][8] > 0.99:
            continue
        g = s.geom_id
        points.append(s.vertices @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g])
    if not points:
        return np.full(3, -1.0), np.full(3, 1.0)
    allp = np.concatenate(points)
    return allp.min(0), allp.max(0)


def camera_for(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera ``(position, look_at)`` that frames the box ``lo``-``hi`` from the front-left,
    above (x forward, z up), whatever the scene's size: a Panda on its table or a 8 m arena."""
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.3)
    direction = np.array([-1.0, -0.9, 0.9])
    return centre + direction / np.linalg.norm(direction) * radius * 1.9, centre
