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
return (nothing within range, or a lost return): the ray is free up to ``range_max``. The
simulated world writes :func:`server.sensors.no_return` (``range_max + 1``) for it; a bridge may
write any finite value outside the band (0 where ``range_min > 0``, as many drivers do), never
NaN or inf, which the protocol refuses. The world's own robot is never a return: a ray that
meets it first is no return (docs/protocol.md, "Scans").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

SCAN_KINDS = ("lidar", "depth")
MAX_RAYS = 4096  # a lidar reading's rays
MAX_PIXELS = 320 * 240  # a depth reading's
MAX_NAME = 64  # characters of a sensor's name
MAX_TIME = 1e9  # world seconds, as a state's time
MAX_POSITION = 1e5  # m from the world's origin: a sensor farther off is a broken pose
MAX_RANGE = 1e4  # m
QUAT_TOLERANCE = 1e-3  # | |quat| - 1 | above this is not a rotation but a broken pose


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


def check_scan(scan: Scan) -> Scan:
    """``scan`` as a planner may rely on it (float64 arrays, its quaternion normalised), or a
    ValueError naming the first field that is not: an unknown kind, a name not of 1 to 64
    characters, a time outside [0, 1e9], a position not [3] finite within 1e5 m, a quaternion
    not [4] of norm 1 (within 1e-3), ranges not finite or of the wrong shape (lidar [N], N <=
    4096; depth [H, W], H·W <= 320·240), a band not 0 <= range_min < range_max <= 1e4, a lidar's
    angles beyond ±2π, a depth camera's ``fovy`` outside (0, 180)."""
    if scan.kind not in SCAN_KINDS:
        raise ValueError(f"kind {scan.kind!r} (expected one of {', '.join(SCAN_KINDS)})")
    if not isinstance(scan.name, str) or not 0 < len(scan.name) <= MAX_NAME:
        raise ValueError(f"name: expected a string of 1 to {MAX_NAME} characters")
    numbers = [scan.time, scan.range_min, scan.range_max, scan.angle_min, scan.angle_increment]
    if not all(math.isfinite(v) for v in numbers + [scan.fovy]):
        raise ValueError("time, range_min, range_max, angles and fovy must be finite")
    if not 0.0 <= scan.time <= MAX_TIME:
        raise ValueError(f"time {scan.time} s (expected world seconds in [0, {MAX_TIME:g}])")
    pos, quat = (np.asarray(v, dtype=float) for v in (scan.pos, scan.quat))
    if pos.shape != (3,) or not np.all(np.abs(pos) <= MAX_POSITION):
        raise ValueError(f"pos: expected [3] finite metres within {MAX_POSITION:g} of the origin")
    norm = float(np.linalg.norm(quat)) if quat.shape == (4,) else math.nan
    if not abs(norm - 1.0) <= QUAT_TOLERANCE:
        raise ValueError(f"quat: expected a unit quaternion [4] (w, x, y, z), norm {norm:.6g}")
    ranges = np.asarray(scan.ranges)
    if ranges.dtype.kind != "f" or not np.all(np.isfinite(ranges)):
        raise ValueError("ranges: expected finite floats (no return: a value outside the band)")
    _check_shape(scan.kind, ranges.shape)
    if not 0.0 <= scan.range_min < scan.range_max <= MAX_RANGE:
        raise ValueError(
            f"range_min {scan.range_min}, range_max {scan.range_max} (expected 0 <= "
            f"range_min < range_max <= {MAX_RANGE:g} m)"
        )
    if scan.kind == "lidar" and max(abs(scan.angle_min), abs(scan.angle_increment)) > 2 * math.pi:
        raise ValueError("angle_min and angle_increment: expected radians within ±2π")
    if scan.kind == "depth" and not 0.0 < scan.fovy < 180.0:
        raise ValueError(f"fovy {scan.fovy} (expected degrees in (0, 180))")
    return dataclasses.replace(
        scan, pos=pos, quat=quat / norm, ranges=ranges.astype(float, copy=False)
    )


def _check_shape(kind: str, shape: tuple[int, ...]) -> None:
    if kind == "lidar" and not (len(shape) == 1 and 0 < shape[0] <= MAX_RAYS):
        raise ValueError(f"ranges: a lidar's are [N], 1 <= N <= {MAX_RAYS}, got {list(shape)}")
    if kind == "depth" and not (
        len(shape) == 2 and min(shape) > 0 and shape[0] * shape[1] <= MAX_PIXELS
    ):
        raise ValueError(
            f"ranges: a depth image's are [height, width], at most {MAX_PIXELS} pixels, "
            f"got {list(shape)}"
        )


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
