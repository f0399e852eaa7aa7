"""A reading's rays and returns in the world frame, from the sensor's pose it is stamped with
(the rays' geometry in the sensor's frame: :func:`shared.scans.ray_directions`)."""

from __future__ import annotations

import numpy as np

from shared.scans import Scan, ray_directions


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
