"""Self-filtering: what the planner models already is not fused into its map as an obstacle.

A camera that watches an arm sees the arm, the cube in its hand and the cubes on the table.
The planner knows all of them (its model holds the robot and the free objects, at the poses of
each state), and its map must not: a carried cube fused as an obstacle would sit wherever the
hand just was. As STORM's and cuRobo's pipelines do, every scan is filtered against spheres that
hold those bodies at the scan's time, padded: a ray's evidence ends where it first enters one
(:func:`clip_rays`). The cells it crossed before are free; the return it ends in, if any, is not
fused, and neither is anything beyond: a body hides what lies behind it, so the map keeps what
it held there. A world that reports no return for the robot (the simulated one does,
``server/sensors.py``) is read right this way too: such a ray is free up to the robot, not
through it, and an obstacle the arm passes in front of is not cleared.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from planner_client.perception.occupancy import Rays


def clip_rays(rays: Rays, spheres: np.ndarray) -> Rays:
    """``rays`` whose evidence ends where each first enters one of ``spheres [n, 4]`` (centre
    x, y, z and radius, m, world frame; a 2-D map's rays meet their discs in its plane): a ray
    that meets one before its end (its return, or how far it is known free) ends there without
    a return."""
    if len(spheres) == 0 or len(rays.ends) == 0:
        return rays
    d = rays.dirs.shape[1]
    oc = spheres[:, :d] - rays.origin  # [n, d] the centres from the sensor
    # [M, n] the centres' positions along each ray (a transposed operand is 50 times slower)
    along = rays.dirs @ np.ascontiguousarray(oc.T)
    disc = along * along
    disc -= np.einsum("nd,nd->n", oc, oc) - spheres[:, 3] ** 2  # [M, n] > 0: the line crosses
    ray, sphere = np.nonzero(disc > 0.0)  # few pairs cross: the roots are taken for them alone
    mid, root = along[ray, sphere], np.sqrt(disc[ray, sphere])
    ahead = mid + root > 0.0  # not behind the sensor
    ray, entry = ray[ahead], np.maximum(mid[ahead] - root[ahead], 0.0)
    first = np.full(len(rays.ends), np.inf)
    np.minimum.at(first, ray, entry)  # [M] where each ray enters its first sphere
    cut = first < rays.ends
    if not cut.any():
        return rays
    return dataclasses.replace(rays, ends=np.where(cut, first, rays.ends), hit=rays.hit & ~cut)
