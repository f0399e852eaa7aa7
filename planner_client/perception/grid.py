"""A regular grid of cells in the world frame, 2-D ``[H, W]`` or 3-D ``[D, H, W]``, laid out as
:class:`planner_client.perception.field.DistanceField` reads it: ``origin`` is the first cell's
centre (x, y[, z]), x runs along the last array axis, y along the one before it, z along the
first of a 3-D grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# cells a side at most: the ray caster's fixed-point positions (raycast.py) stay in int32
MAX_CELLS = 8192


@dataclass(frozen=True)
class GridSpec:
    """Cells of ``resolution`` m; ``origin`` (x, y[, z]) the first cell's centre, ``shape`` the
    array's ((H, W) or (D, H, W): rows along y, columns along x)."""

    origin: tuple[float, ...]
    resolution: float
    shape: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.shape) not in (2, 3) or len(self.origin) != len(self.shape):
            raise ValueError(f"a grid is 2-D or 3-D: origin {self.origin}, shape {self.shape}")
        if not (self.resolution > 0 and 0 < min(self.shape) and max(self.shape) <= MAX_CELLS):
            raise ValueError(
                f"resolution {self.resolution} must be > 0 and shape {self.shape} in"
                f" [1, {MAX_CELLS}] a side"
            )

    @classmethod
    def box(cls, lo: tuple[float, ...], hi: tuple[float, ...], resolution: float) -> GridSpec:
        """The grid whose cells cover the box ``[lo, hi]`` (x, y[, z]), m (at least one cell a
        side; the far faces rounded up to whole cells)."""
        lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
        n = np.maximum(np.ceil((hi_a - lo_a) / resolution - 1e-9), 1).astype(int)
        origin = tuple(float(v) for v in lo_a + resolution / 2)
        return cls(origin, float(resolution), tuple(int(v) for v in n[::-1]))

    @property
    def dims(self) -> int:
        """2 or 3."""
        return len(self.shape)

    @property
    def size_xyz(self) -> np.ndarray:
        """``[d]`` cells along x, y[, z]."""
        return np.array(self.shape[::-1])

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The box the cells cover: its low and high corners ``[d]`` (x, y[, z]), m."""
        o = np.asarray(self.origin)
        return o - self.resolution / 2, o + (self.size_xyz - 0.5) * self.resolution

    @property
    def strides_xyz(self) -> np.ndarray:
        """``[d]`` how far the flat (C-order) index moves for one cell along x, y[, z]."""
        return np.array([math.prod(self.shape[self.dims - a :]) for a in range(self.dims)])

    def centres(self) -> np.ndarray:
        """``[*shape, d]`` every cell's centre (x, y[, z]), m."""
        axes = [
            self.origin[a] + np.arange(n) * self.resolution for a, n in enumerate(self.size_xyz)
        ]
        mesh = np.meshgrid(*axes[::-1], indexing="ij")  # array order: [z,] y, x
        return np.stack(mesh[::-1], axis=-1)

    def flat_index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cells holding ``points [N, d]``: flat (C-order) indices ``[N]`` and whether each
        point lies in the grid ``[N]`` (the index of one outside is clipped, not meaningful)."""
        cell = np.rint((points - np.asarray(self.origin)) / self.resolution).astype(np.int64)
        inside = ((cell >= 0) & (cell < self.size_xyz)).all(axis=1)
        cell = np.clip(cell, 0, self.size_xyz - 1)
        return cell @ self.strides_xyz, inside
