"""A margin kept from obstacles that the planner knows only through its map: the robot's
collision spheres (:mod:`planner_client.spheres`) looked up in the newest signed distance field
(:mod:`planner_client.perception.field`) at every rollout step. Returns ``[S, T]``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch

from planner_client.costs.base import CostTerm, FieldSource, register
from planner_client.costs.helpers import constant, last_sum
from planner_client.sensors import SensorRequest
from planner_client.spheres import Sphere, robot_spheres
from shared.config import positive, string_list

if TYPE_CHECKING:
    from planner_client.perception.field import DistanceField


@register("perceived_clearance")
@dataclass
class PerceivedClearance(CostTerm):
    """Σ_i (max(0, margin − (d(c_i) − r_i)) / margin)² over the robot's collision spheres i
    (centre c_i, radius r_i) of the bodies ``bodies`` (default: every body that has spheres),
    d the newest signed distance field of the planner's map: 0 while every sphere is at least
    ``margin`` m from what the map holds, 1 per sphere at touching, growing quadratically with
    penetration (the shape of ``clearance``). 0 while there is no field yet.

    The spheres' centres are the ``framepos`` sensors of a site per sphere, ``[S, T, n, 3]``,
    looked up in the field all at once (:meth:`DistanceField.lookup`); a 2-D field (a base's
    map) reads their x and y only, so an arm's spheres count there at any height: list the
    base's bodies in ``bodies`` then. ``margin`` is required (metres).

    ``objects`` (default none) adds bodies of the planner's model that are not the robot's, a
    sphere each round its origin holding its collision geoms (the ``framepos`` of the body):
    a cube carried in the hand keeps the margin too."""

    bodies: tuple[str, ...]
    margin: float
    spheres: tuple[Sphere, ...] = field(repr=False, compare=False)
    source: FieldSource | None = field(default=None, repr=False, compare=False)
    objects: tuple[str, ...] = ()
    object_radii: tuple[float, ...] = field(default=(), repr=False, compare=False)
    # the newest field moved to the batch's device: (the field, the copy)
    _moved: tuple[DistanceField, DistanceField] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    @classmethod
    def from_params(cls, s, ctx):
        margin = s.req("margin", positive, "metres > 0")  # declared, never a default
        spheres = robot_spheres(ctx.resolve.model, ctx.resolve, ctx.robot)
        known = tuple(dict.fromkeys(sp.body for sp in spheres))
        expected = f"bodies of the robot with collision spheres: {', '.join(known)}"
        bodies = s.opt("bodies", known, string_list, expected)
        for i, body in enumerate(bodies):
            if body not in known:
                raise s.error(f"bodies[{i}]", "no collision spheres", body, expected)
        if not bodies:
            raise s.error("bodies", "no bodies", [], expected)
        chosen = tuple(sp for sp in spheres if sp.body in bodies)
        objects = s.opt("objects", (), string_list, "bodies of the model, not the robot's")
        radii = tuple(_object_radius(s, ctx, known, i, name) for i, name in enumerate(objects))
        return cls(
            bodies=tuple(bodies),
            margin=margin,
            spheres=chosen,
            source=ctx.field_source,
            objects=tuple(objects),
            object_radii=radii,
        )

    def sensors(self):
        spheres = [SensorRequest("framepos", sp.frame) for sp in self.spheres]
        return spheres + [SensorRequest("framepos", name) for name in self.objects]

    def centres(self, batch) -> torch.Tensor:
        """The spheres' centres ``[S, T, n, 3]`` (world frame, m), in :attr:`spheres`' order,
        then the objects'."""
        return batch.columns.take_all(batch.sensordata, self.requests).unflatten(-1, (-1, 3))

    def __call__(self, batch):
        sd = batch.sensordata
        latest = self.source.latest() if self.source is not None else None
        if latest is None:
            return sd.new_zeros(batch.controls.shape[:2])
        d = self._on(latest, sd).lookup(self.centres(batch))  # [S, T, n]
        radii = tuple(sp.radius for sp in self.spheres) + self.object_radii
        radii = constant(radii, sd.dtype, sd.device)
        x = torch.clamp(self.margin + radii - d, min=0.0) / self.margin
        return last_sum(x * x)

    def _on(self, latest: DistanceField, like: torch.Tensor) -> DistanceField:
        """``latest`` with its values of ``like``'s dtype on its device, moved once per field
        (the map is published on the CPU; a warp backend's rollouts are on a GPU)."""
        if self._moved is None or self._moved[0] is not latest:
            values = latest.values.to(like)
            self._moved = (latest, dataclasses.replace(latest, values=values))
        return self._moved[1]


def _object_radius(s, ctx, robot: tuple[str, ...], i: int, name: str) -> float:
    """The radius round body ``name``'s origin that holds its collision geoms, m (``objects[i]``
    checked: a body of the model, not the robot's, with collision geoms)."""
    key = f"objects[{i}]"
    ctx.resolve.checked(name, s.source, s.key_path(key))
    model = ctx.resolve.model
    frame = ctx.resolve(name)
    if frame.kind != mujoco.mjtObj.mjOBJ_BODY:
        raise s.error(key, "not a body", name, "a body of the model: an object's name")
    if name in robot:
        raise s.error(key, "a body of the robot", name, "the robot's bodies go in bodies")
    start, n = model.body_geomadr[frame.id], model.body_geomnum[frame.id]
    reach = [
        float(np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g])
        for g in range(start, start + n)
        if model.geom_contype[g] or model.geom_conaffinity[g]
    ]
    if not reach:
        raise s.error(key, "no collision geoms", name, "a body that collides")
    return max(reach)
