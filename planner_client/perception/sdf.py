"""Signed distance fields on a :class:`GridSpec`: from an occupancy map (an exact Euclidean
distance transform, ``scipy.ndimage.distance_transform_edt``), from the scenario's known
obstacle footprints (:func:`planner_client.global_path.signed_distance`, exact) or solids in
3-D (:func:`solid_field`, exact), and their union (:func:`compose`, the elementwise min). Each is
a :class:`DistanceField`.

An occupied cell stands for a square (cube) of one cell: a free cell's distance is the one to
the nearest occupied cell's centre less half a cell, an occupied cell's is minus the one to the
nearest free cell's centre less half a cell; so the surface lies half-way between the two, and
a surface cell seen from outside reads about ``-resolution / 2``. A map only sees the surface of
an obstacle: its inside is unknown, and so free, in the field (a shell, one cell thick, that a
margin keeps the robot away from).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from planner_client.global_path import Shape, signed_distance
from planner_client.perception.field import DistanceField
from planner_client.perception.grid import GridSpec


def far(spec: GridSpec) -> float:
    """A distance no cell can have to an obstacle in the grid: its diagonal, m (the value of a
    grid with nothing in it; finite, so the field interpolates)."""
    lo, hi = spec.bounds
    return float(np.linalg.norm(hi - lo))


def distance_field(occupied: np.ndarray, spec: GridSpec, time: float = 0.0) -> DistanceField:
    """The signed distance field of ``occupied`` (bool, ``spec.shape``), m, negative inside."""
    # imported here: scipy.ndimage costs a tenth of the planner's start-up, and only maps need it
    from scipy.ndimage import distance_transform_edt

    if occupied.shape != spec.shape:
        raise ValueError(f"occupancy {occupied.shape} does not match the grid {spec.shape}")
    res, limit = spec.resolution, far(spec)
    half = res / 2
    if not occupied.any():
        values = np.full(spec.shape, limit)
    elif occupied.all():
        values = np.full(spec.shape, -limit)
    else:
        # the EDT gives each nonzero cell its distance to the nearest zero cell's centre
        values = distance_transform_edt(~occupied, sampling=res) - half
        box = _around(occupied)
        values[box] = np.where(
            occupied[box], half - distance_transform_edt(occupied[box], sampling=res), values[box]
        )
    return _field(values, spec, time)


def known_field(
    shapes: list[Shape],
    spec: GridSpec,
    z: tuple[float, float] | None = None,
    time: float = 0.0,
) -> DistanceField:
    """The signed distance of known obstacle footprints (the guide's :class:`Shape`: boxes,
    disks, wall half-planes) at the grid's cell centres. A 3-D grid extrudes them over the
    heights ``z`` (lo, hi, m), which it needs; a 2-D grid takes no ``z``. With no shapes every
    cell is :func:`far`."""
    if (z is None) != (spec.dims == 2):
        raise ValueError("a 3-D grid extrudes shapes over z = (lo, hi); a 2-D one takes no z")
    limit = far(spec)
    centres = spec.centres()
    plane = centres[0] if spec.dims == 3 else centres  # [H, W, d]: every layer has the same xy
    d2 = signed_distance(shapes, plane[..., :2].reshape(-1, 2)).reshape(plane.shape[:2])
    d2 = np.minimum(d2, limit)
    if z is None:
        return _field(d2, spec, time)
    lo, hi = z
    zc = centres[:, 0, 0, 2][:, None, None]  # [D, 1, 1]
    dz = np.abs(zc - (lo + hi) / 2) - (hi - lo) / 2
    # a prism's distance from its footprint's and its height band's, as a box's from its axes'
    out = np.hypot(np.maximum(d2, 0.0), np.maximum(dz, 0.0))
    values = out + np.minimum(np.maximum(d2, dz), 0.0)
    return _field(np.minimum(values, limit), spec, time)


@dataclass(frozen=True)
class Solid:
    """A known obstacle's geom in the world frame: ``kind`` (``box``, ``sphere``, ``capsule``,
    ``cylinder`` or ``plane``), MuJoCo's half-sizes ``size [3]``, centre ``pos [3]`` and axes
    ``rot [3, 3]`` (columns, the geom's x, y, z in the world frame). A plane is the half-space
    below it (behind its z axis)."""

    kind: str
    size: tuple[float, float, float]
    pos: tuple[float, float, float]
    rot: tuple[tuple[float, float, float], ...]

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance ``[N]`` of ``points [N, 3]`` (world frame, m), negative inside."""
        local = (points - np.asarray(self.pos)) @ np.asarray(self.rot)  # [N, 3] in its axes
        a, b, h = self.size
        if self.kind == "plane":
            return local[:, 2]
        if self.kind == "sphere":
            return np.linalg.norm(local, axis=1) - a
        if self.kind == "capsule":
            axial = local[:, 2] - np.clip(local[:, 2], -b, b)
            return np.hypot(np.hypot(local[:, 0], local[:, 1]), axial) - a
        if self.kind == "cylinder":
            q = np.stack([np.hypot(local[:, 0], local[:, 1]) - a, np.abs(local[:, 2]) - b], 1)
        elif self.kind == "box":
            q = np.abs(local) - np.array([a, b, h])
        else:
            raise ValueError(f"a solid is a box, sphere, capsule, cylinder or plane: {self.kind}")
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        return outside + np.minimum(q.max(axis=1), 0.0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The low and high corners ``[3]`` of its axis-aligned bounding box (a plane's is
        the whole space), m."""
        rot, (a, b, h) = np.abs(np.asarray(self.rot)), self.size
        if self.kind == "plane":
            return np.full(3, -np.inf), np.full(3, np.inf)
        if self.kind == "box":
            half = rot @ np.array([a, b, h])
        elif self.kind == "sphere":
            half = np.full(3, a)
        elif self.kind == "capsule":  # its segment and a ball round it
            half = b * rot[:, 2] + a
        else:  # a cylinder: its axis' reach and its end discs'
            half = b * rot[:, 2] + a * np.sqrt(np.clip(1.0 - rot[:, 2] ** 2, 0.0, 1.0))
        return np.asarray(self.pos) - half, np.asarray(self.pos) + half


def solid_field(solids: list[Solid], spec: GridSpec, time: float = 0.0) -> DistanceField:
    """The signed distance of the union of ``solids`` at the cell centres of a 3-D grid, exact
    (each solid's own distance, their min), at most :func:`far`."""
    if spec.dims != 3:
        raise ValueError("solids are measured on a 3-D grid")
    points = spec.centres().reshape(-1, 3)
    values = np.full(points.shape[0], far(spec))
    for s in solids:
        np.minimum(values, s.distance(points), out=values)
    return _field(values.reshape(spec.shape), spec, time)


def compose(*fields: DistanceField) -> DistanceField:
    """The union of the obstacles of ``fields`` on one grid: their elementwise min, at the
    newest of their times."""
    if not fields:
        raise ValueError("compose needs at least one field")
    first = fields[0]
    for f in fields[1:]:
        same = (f.values.shape, f.origin, f.resolution) == (
            first.values.shape,
            first.origin,
            first.resolution,
        )
        if not same:
            raise ValueError("compose reads fields on one grid (shape, origin and resolution)")
    values = first.values
    for f in fields[1:]:
        values = torch.minimum(values, f.values)
    return DistanceField(
        values, first.origin, first.resolution, max(f.time for f in fields), first.outside
    )


def _around(occupied: np.ndarray) -> tuple[slice, ...]:
    """The box of the occupied cells and one cell round them (clipped to the grid). An occupied
    cell's nearest free cell lies in it: the grid's cells beyond it are free, and one clamped
    into its free border is nearer. The inside's transform is done there only (a map sees
    surfaces: a thin shell in a large grid)."""
    box = []
    for axis in range(occupied.ndim):
        other = tuple(a for a in range(occupied.ndim) if a != axis)
        idx = np.flatnonzero(occupied.any(axis=other))
        box.append(slice(max(int(idx[0]) - 1, 0), int(idx[-1]) + 2))
    return tuple(box)


def _field(values: np.ndarray, spec: GridSpec, time: float) -> DistanceField:
    t = float(time) if math.isfinite(time) else 0.0
    return DistanceField(
        torch.from_numpy(np.ascontiguousarray(values, dtype=np.float64)),
        spec.origin,
        spec.resolution,
        t,
    )
