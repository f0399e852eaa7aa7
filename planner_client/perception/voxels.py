"""A 3-D occupancy map of an arm's workspace from depth cameras (and lidars): a box of the
world in voxels ``[D, H, W]`` (:mod:`occupancy` fuses; this module chooses the rays: all of
them, in 3-D). A camera sees the table or floor it looks at: a box that starts above it leaves
them out (the planner's model holds them, and its contacts keep the arm off them;
:func:`planner_client.maps.default_box`).
"""

from __future__ import annotations

from planner_client.perception.grid import GridSpec
from planner_client.perception.occupancy import MapConfig, OccupancyMap, Rays, scan_rays
from shared.scans import Scan


class VoxelGrid(OccupancyMap):
    """Log-odds ``[D, H, W]`` over the box ``lo`` to ``hi`` (x, y, z, m) in voxels of
    ``cfg.resolution``; reads ``depth`` and ``lidar`` scans."""

    def __init__(
        self, lo: tuple[float, float, float], hi: tuple[float, float, float], cfg: MapConfig
    ):
        super().__init__(GridSpec.box(lo, hi, cfg.resolution), cfg)

    def accepts(self, scan: Scan) -> bool:
        return scan.kind in ("depth", "lidar")

    def rays(self, scan: Scan) -> Rays:
        return scan_rays(scan)
