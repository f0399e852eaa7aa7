"""An occupancy map in log-odds over a :class:`GridSpec`, updated from rays: the cell a return
ends in gains ``l_occ``, every cell a ray crosses before it (or before ``range_max`` for a ray
with no return) gains ``l_free`` (a negative number), each clamped to ``[l_min, l_max]``; a cell
is occupied while its log-odds exceed ``threshold``. A cell counts once per scan whichever
number of its rays cross it, and a return in it outweighs the rays that cross it in the same
scan (as OctoMap does), so a wall seen at a grazing angle is not rubbed out by its own scan.

The clamp is what makes the map forget: a cell held at ``l_max`` is free again after
about ``(l_max - threshold) / -l_free`` scans that see through it
(:meth:`MapConfig.scans_to_clear`), so a person who walked away stops being an obstacle.
:mod:`grid2d` and :mod:`voxels` choose a scan's rays; this module fuses them.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from planner_client.perception.grid import GridSpec
from planner_client.perception.raycast import crossed
from planner_client.perception.rays import world_rays
from planner_client.perception.self_filter import clip_rays
from shared.scans import Scan


@dataclass(frozen=True)
class MapConfig:
    """A map's parameters.

    Attributes:
        resolution: cell size, m.
        l_occ: log-odds added to a cell a return ends in (> 0).
        l_free: log-odds added to a cell a ray crosses (< 0).
        l_min, l_max: the clamp of a cell's log-odds (``l_min < threshold < l_max``).
        threshold: a cell is occupied while its log-odds exceed it.
        max_tilt: a 2-D map's rays: those inclined more than this to its plane are left out,
            rad (a planar lidar's rays lie in the plane; a tilted one would see the floor).
        rate_hz: :class:`planner_client.perception.updater.MapUpdater` recomputes the field at
            most this often in real time.
        max_queue: scans an updater holds before it drops the oldest (a map that cannot keep
            up reads the newest readings rather than fall further behind).
    """

    resolution: float = 0.05
    l_occ: float = 0.85
    l_free: float = -0.4
    l_min: float = -2.0
    l_max: float = 1.9
    threshold: float = 0.0
    max_tilt: float = 0.05
    rate_hz: float = 10.0
    max_queue: int = 64

    def __post_init__(self) -> None:
        if not self.resolution > 0:
            raise ValueError(f"resolution {self.resolution} must be > 0")
        if not (self.l_occ > 0 > self.l_free):
            raise ValueError(f"l_occ {self.l_occ} must be > 0 and l_free {self.l_free} < 0")
        if not (self.l_min < self.threshold < self.l_max):
            raise ValueError(f"need l_min < threshold < l_max: {self}")
        if not (self.rate_hz > 0 and self.max_queue > 0 and 0 <= self.max_tilt < math.pi / 2):
            raise ValueError(f"rate_hz and max_queue must be > 0, max_tilt in [0, pi/2): {self}")

    def scans_to_clear(self) -> int:
        """Scans that see through a cell held at ``l_max`` before it is free again."""
        # counted in the map's float32, as it adds: a sum that lands on the threshold in exact
        # arithmetic may stay a hair above it in float32 (and ceil would be one short)
        value, step, n = np.float32(self.l_max), np.float32(self.l_free), 0
        while value > self.threshold:
            value, n = max(value + step, np.float32(self.l_min)), n + 1
        return n


@dataclass(frozen=True)
class Rays:
    """A scan's rays as a map fuses them: ``origin [d]``, unit ``dirs [M, d]``, ``ends [M]``
    (m: the return's range, or how far a ray with none is known free) and ``hit [M]``."""

    origin: np.ndarray
    dirs: np.ndarray
    ends: np.ndarray
    hit: np.ndarray


class OccupancyMap(ABC):
    """Log-odds ``logodds`` (float32, ``spec.shape``) over ``spec``, updated by :meth:`insert`;
    ``time`` is the world time of the newest scan in it, ``scans`` how many it fused. A
    subclass says which scans it reads (:meth:`accepts`) and which of their rays
    (:meth:`rays`)."""

    def __init__(self, spec: GridSpec, cfg: MapConfig):
        if abs(spec.resolution - cfg.resolution) > 1e-12:
            raise ValueError(f"grid resolution {spec.resolution} != {cfg.resolution}")
        self.spec, self.cfg = spec, cfg
        self.logodds = np.zeros(spec.shape, dtype=np.float32)
        self.time = -math.inf
        self.scans = 0

    @abstractmethod
    def accepts(self, scan: Scan) -> bool:
        """Whether this map reads scans of ``scan``'s kind."""

    @abstractmethod
    def rays(self, scan: Scan) -> Rays:
        """The rays of ``scan`` this map fuses, in its dimensions."""

    def insert(self, scan: Scan, exclude: np.ndarray | None = None) -> None:
        """Fuse one scan (module docstring); a ``ValueError`` for one it does not read.
        ``exclude [n, 4]``: spheres (centre, radius, m) of what the planner models at the
        scan's time, its rays cut where they enter one
        (:func:`planner_client.perception.self_filter.clip_rays`)."""
        if not self.accepts(scan):
            raise ValueError(f"a {type(self).__name__} does not read {scan.kind} scans")
        rays = self.rays(scan)
        if exclude is not None:
            rays = clip_rays(rays, exclude)
        self.integrate(rays)
        self.time = max(self.time, float(scan.time))
        self.scans += 1

    def integrate(self, rays: Rays) -> None:
        """Add one scan's evidence: returns to the cells they end in, misses to the cells the
        rays cross before."""
        cfg = self.cfg
        free = crossed(self.spec, rays.origin, rays.dirs, rays.ends)
        occ = np.zeros_like(free)
        ends = rays.origin + rays.dirs[rays.hit] * rays.ends[rays.hit, None]
        idx, inside = self.spec.flat_index(ends)
        occ[idx[inside]] = True
        free &= ~occ
        lo = self.logodds.reshape(-1)
        lo[free] += cfg.l_free
        lo[occ] += cfg.l_occ
        np.clip(lo, cfg.l_min, cfg.l_max, out=lo)

    def occupied(self) -> np.ndarray:
        """``spec.shape`` bool: the cells held occupied now."""
        return self.logodds > self.cfg.threshold


def scan_rays(scan: Scan) -> Rays:
    """All of a scan's rays in the world frame (3-D): ``ends`` the range of a return, or
    ``range_max`` for a ray without one (free that far)."""
    origin, dirs = world_rays(scan)
    hit = scan.hits().reshape(-1)
    ends = np.where(hit, scan.ranges.reshape(-1), scan.range_max).astype(float)
    return Rays(origin, dirs, ends, hit)
