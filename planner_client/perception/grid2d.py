"""A 2-D occupancy map of the plane from a base's lidar (:mod:`occupancy` fuses; this module
chooses the rays): a rectangle of the world's x-y plane, e.g. the arena and a margin.

A planar lidar's rays lie in its plane; only those within ``max_tilt`` of the map's plane count
(a tilted robot's lidar would otherwise see the floor), and they are projected onto it: the z of
the sensor and of its returns is ignored, so the map holds whatever the lidar's plane cuts.
"""

from __future__ import annotations

import math

import numpy as np

from planner_client.perception.grid import GridSpec
from planner_client.perception.occupancy import MapConfig, OccupancyMap, Rays, scan_rays
from shared.scans import Scan


class OccupancyGrid2D(OccupancyMap):
    """Log-odds ``[H, W]`` over the rectangle ``lo`` to ``hi`` (x, y, m) in cells of
    ``cfg.resolution``; reads ``lidar`` scans."""

    def __init__(self, lo: tuple[float, float], hi: tuple[float, float], cfg: MapConfig):
        super().__init__(GridSpec.box(lo, hi, cfg.resolution), cfg)

    @classmethod
    def arena(cls, half_size: float, margin: float, cfg: MapConfig) -> OccupancyGrid2D:
        """A map over the square ``±(half_size + margin)`` round the origin (a scenario's
        ``world.arena.half_size``; the margin keeps the walls' faces inside)."""
        h = half_size + margin
        return cls((-h, -h), (h, h), cfg)

    def accepts(self, scan: Scan) -> bool:
        return scan.kind == "lidar"

    def rays(self, scan: Scan) -> Rays:
        """The scan's rays near the plane ``[M', 2]``, their lengths scaled to the plane."""
        r = scan_rays(scan)
        dz = np.abs(r.dirs[:, 2])
        keep = dz <= math.sin(self.cfg.max_tilt)
        flat = np.sqrt(1.0 - dz[keep] ** 2)  # how much of a metre along the ray lies in-plane
        return Rays(
            r.origin[:2],
            r.dirs[keep, :2] / flat[:, None],
            r.ends[keep] * flat,
            r.hit[keep],
        )
