"""Signed distance fields on a :class:`GridSpec`: from an occupancy map (an exact Euclidean
distance transform, ``scipy.ndimage.distance_transform_edt``), from the scenario's known
obstacle shapes (:func:`planner_client.global_path.signed_distance`, exact), and their union
(:func:`compose`, the elementwise min). Each is a :class:`DistanceField`.

An occupied cell stands for a square (cube) of one cell: a free cell's distance is the one to
the nearest occupied cell's centre less half a cell, an occupied cell's is minus the one to the
nearest free cell's centre less half a cell; so the surface lies half-way between the two, and
a surface cell seen from outside reads about ``-resolution / 2``. A map only sees the surface of
an obstacle: its inside is unknown, and so free, in the field (a shell, one cell thick, that a
margin keeps the robot away from).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt

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
