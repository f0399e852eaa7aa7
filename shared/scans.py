"""Range readings of a robot's sensors, as a world sends them and a planner reads them: a 2-D
lidar's scan (in the spirit of ROS's ``sensor_msgs/LaserScan``) and a depth camera's image of
ray lengths (``sensor_msgs/Image`` with its ``CameraInfo``, read as a point cloud).

A reading is stamped with the world time of its measurement and the sensor's pose in the world
frame then, so the planner needs no model of where the sensor sits. Its rays, in the sensor's
frame (:func:`ray_directions`):

- ``lidar``: ``N`` rays in the sensor's x-y plane, ray ``i`` at angle ``angle_min + i ·
  angle_increment`` (rad) from the sensor's x axis towards its y axis;
- ``depth``: a pinhole camera looking along the sensor's +z, image x (columns, ``width``) along
  the sensor's +x and image y (rows, ``height``) along its +y (OpenCV's convention), vertical
  field of view ``fovy`` (deg), square pixels; ``ranges [height, width]`` are ray lengths, not
  z-depths.

``ranges`` are metres along each ray, finite; a value outside ``[range_min, range_max]`` is no
return (nothing within range, or a lost return): the ray is free up to ``range_max``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SCAN_KINDS = ("lidar", "depth")


@dataclass
class Scan:
    """One sensor's reading at world time ``time``.

    Attributes:
        name: the sensor's name in the scenario (``sensors[].name``).
        kind: ``lidar`` or ``depth``.
        time: world seconds of the measurement (a reading may be older than the state it
            travels with: a sensor's own rate and latency).
        pos: ``[3]`` the sensor's origin in the world frame, m.
        quat: ``[4]`` its orientation in the world frame, (w, x, y, z), unit.
        ranges: lidar ``[N]``, depth ``[height, width]``: metres along each ray.
        range_min, range_max: the valid band of ``ranges``, m, ``0 <= range_min < range_max``.
        angle_min, angle_increment: lidar only, rad.
        fovy: depth only, the vertical field of view, deg in (0, 180).
    """

    name: str
    kind: str
    time: float
    pos: np.ndarray
    quat: np.ndarray
    ranges: np.ndarray
    range_min: float
    range_max: float
    angle_min: float = 0.0
    angle_increment: float = 0.0
    fovy: float = 0.0

    def hits(self) -> np.ndarray:
        """``[...]`` bool, the shape of ``ranges``: which rays returned within range."""
        return (self.ranges >= self.range_min) & (self.ranges <= self.range_max)


def ray_directions(scan: Scan) -> np.ndarray:
    """Unit ray directions ``[..., 3]`` in the sensor's frame, the shape of ``scan.ranges``."""
    if scan.kind == "lidar":
        angles = scan.angle_min + scan.angle_increment * np.arange(scan.ranges.shape[0])
        return np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=-1)
    height, width = scan.ranges.shape
    f = 0.5 * height / math.tan(math.radians(scan.fovy) / 2)  # focal length, pixels
    u = (np.arange(width) + 0.5 - width / 2) / f
    v = (np.arange(height) + 0.5 - height / 2) / f
    d = np.stack(np.broadcast_arrays(u[None, :], v[:, None], np.ones((height, width))), axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def rotation(quat: np.ndarray) -> np.ndarray:
    """``[3, 3]`` rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(q) for q in quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def world_rays(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """The rays in the world frame: origin ``[3]`` and unit directions ``[M, 3]`` (``M`` the
    number of rays, ``ranges`` flattened in C order)."""
    d = ray_directions(scan).reshape(-1, 3) @ rotation(scan.quat).T
    return np.asarray(scan.pos, dtype=float), d


def world_points(scan: Scan) -> np.ndarray:
    """``[K, 3]`` the returns within range as points in the world frame."""
    origin, d = world_rays(scan)
    r = scan.ranges.reshape(-1)
    hit = scan.hits().reshape(-1)
    return origin + d[hit] * r[hit, None]
