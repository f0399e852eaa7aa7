"""The robot's collision shape as spheres per body, for cost terms that look points up in a
signed distance field (:mod:`planner_client.costs.perceived`).

A body's spheres are the robot file's ``spheres:`` for it (:class:`shared.robots.RobotSpec`),
else derived from the MJCF's collision geoms of that body (:func:`geom_spheres`). The planner's
model gets a site at each sphere's centre that a term uses (:func:`add_sphere_sites`), so the
``framepos`` sensors of those sites give the centres along every rollout, ``[S, T, n, 3]``.
Only the planner needs them: the world simulates the robot's own geoms.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np

from shared.frames import FrameResolver
from shared.robots import RobotSpec

SITE_PREFIX = "m3p2i_sphere"  # the spheres' sites: m3p2i_sphere__BODY__INDEX

# (x, y, z, r): a sphere in its body's frame, m
Ball = tuple[float, float, float, float]


class Sphere(NamedTuple):
    """A collision sphere: its ``body``, centre ``pos`` in the body's frame and ``radius`` (m),
    and the name of its ``site`` in the planner's model."""

    body: str
    pos: tuple[float, float, float]
    radius: float
    site: str

    @property
    def frame(self) -> str:
        """The site as a YAML frame name (``site:NAME``), for sensor requests."""
        return f"site:{self.site}"


def geom_spheres(model: mujoco.MjModel, g: int) -> list[Ball]:
    """Spheres ``(x, y, z, r)`` in the frame of geom ``g``'s body whose union holds the geom: a
    sphere is itself; a capsule, cylinder or box is cut along its long axis into slices no
    longer than its cross-section's radius c, each held by one sphere (a long link is several
    spheres of radius at most 1.12 c, not one of its half length); any other geom
    (an ellipsoid, a mesh) is its bounding sphere."""
    t, size = int(model.geom_type[g]), model.geom_size[g]
    pos = model.geom_pos[g]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    rot = rot.reshape(3, 3)  # columns: the geom's axes in the body's frame
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return [(*pos.tolist(), float(size[0]))]
    if t in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
        axis, c, h = rot[:, 2], float(size[0]), float(size[1])
    elif t == mujoco.mjtGeom.mjGEOM_BOX:
        k = int(np.argmax(size))
        axis, h = rot[:, k], float(size[k])
        c = math.hypot(*(float(size[i]) for i in range(3) if i != k))
    else:
        return [(*pos.tolist(), float(model.geom_rbound[g]))]
    n = max(1, math.ceil(2 * h / c))
    if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
        # the capsule is every point within c of its segment: centres on the segment, its ends
        # included, each within h / n of every point of it along the axis
        offsets = np.linspace(-h, h, n + 1)
    else:  # flat ends: a sphere at the middle of each slice
        offsets = -h + (2 * np.arange(n) + 1) * h / n
    r = math.hypot(c, h / n)
    return [(*(pos + o * axis).tolist(), r) for o in offsets]


def derive_spheres(
    model: mujoco.MjModel, bodies: list[int] | None = None
) -> dict[str, tuple[Ball, ...]]:
    """The spheres (:func:`geom_spheres`) of the geoms that collide (``contype`` or
    ``conaffinity`` non-zero; planes left out) of ``bodies`` (default: every body but the
    world), by body name; a body without colliding geoms has none."""
    out: dict[str, tuple[Ball, ...]] = {}
    for body in range(1, model.nbody) if bodies is None else bodies:
        start, count = model.body_geomadr[body], model.body_geomnum[body]
        balls = [
            ball
            for g in range(start, start + count)
            if (model.geom_contype[g] or model.geom_conaffinity[g])
            and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE
            for ball in geom_spheres(model, g)
        ]
        if balls:
            out[model.body(body).name] = tuple(balls)
    return out


def robot_bodies(model: mujoco.MjModel, resolve: FrameResolver) -> list[int]:
    """The robot's bodies in a scenario's ``model``: the tree of the world's child that holds
    the robot's frame (a robot MJCF is the model's first tree; the world's objects are others)."""
    frame = resolve("robot")
    body = frame.id if frame.kind == mujoco.mjtObj.mjOBJ_BODY else int(model.site_bodyid[frame.id])
    root = int(model.body_rootid[body])
    return [b for b in range(1, model.nbody) if int(model.body_rootid[b]) == root]


def robot_spheres(
    model: mujoco.MjModel, resolve: FrameResolver, robot: RobotSpec | None = None
) -> tuple[Sphere, ...]:
    """The robot's collision spheres in a scenario's ``model``: per body of the robot
    (:func:`robot_bodies`), the robot file's ``spheres:`` where it declares that body, else the
    ones derived from the body's geoms (:func:`derive_spheres`); bodies in the model's order,
    declared ones it derives none for after them."""
    balls = derive_spheres(model, robot_bodies(model, resolve))
    balls.update(robot.spheres if robot is not None else ())
    return tuple(
        Sphere(body, (x, y, z), r, f"{SITE_PREFIX}__{body}__{i}")
        for body, items in balls.items()
        for i, (x, y, z, r) in enumerate(items)
    )


def add_sphere_sites(spec: mujoco.MjSpec, spheres: tuple[Sphere, ...], frames: set[str]) -> None:
    """A site at the centre of each sphere whose frame (``site:NAME``) is in ``frames`` (what
    the terms request), on its body in ``spec``, before the planner's model is compiled: a
    model none of whose terms reads them has none."""
    for s in spheres:
        if s.frame in frames:
            spec.body(s.body).add_site(
                name=s.site, pos=list(s.pos), size=[s.radius, 0.0, 0.0], group=5
            )
