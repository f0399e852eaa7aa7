"""A signed distance field on a regular grid in the world frame, and its lookup for a batch of
points in torch (bilinear in 2-D, trilinear in 3-D, as ``torch.nn.functional.grid_sample``).

Cell ``(i, j)`` of a 2-D field ``[H, W]`` is centred at ``origin + (j, i) · resolution`` (x along
columns, y along rows); cell ``(k, i, j)`` of a 3-D field ``[D, H, W]`` at ``origin + (j, i, k) ·
resolution``. Values are metres, negative inside an obstacle. A point outside the grid is
``outside`` m from any obstacle the field knows (far: the map holds every obstacle it saw).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class DistanceField:
    """Signed distances ``values`` ([H, W] or [D, H, W]), float64, with the grid's ``origin``
    (the first cell's centre, (x, y) or (x, y, z), m), cell size ``resolution`` (m) and the
    world ``time`` of the newest reading in it."""

    values: torch.Tensor
    origin: tuple[float, ...]
    resolution: float
    time: float = 0.0
    outside: float = 1e3

    @property
    def dims(self) -> int:
        return self.values.dim()

    @functools.cached_property
    def _to_grid(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(origin [d], cells [d])`` on the values' dtype and device: the first cell's centre
        and the cells between the outer centres along x, y[, z] (at least 1). Made once per
        field, not once per lookup (a cost term looks up every iteration)."""
        like = dict(dtype=self.values.dtype, device=self.values.device)
        size = torch.tensor(self.values.shape[::-1], **like)  # x, y[, z]
        return torch.tensor(self.origin, **like), (size - 1).clamp(min=1)

    def lookup(self, points: torch.Tensor) -> torch.Tensor:
        """Signed distance at ``points [..., d]`` (d = 2 or 3, world frame; a 2-D field reads
        x and y of 3-D points) -> ``[...]``, interpolated between cell centres."""
        d = self.dims
        p = points[..., :d].to(self.values)
        origin, cells = self._to_grid
        # grid_sample's [-1, 1] spans the outer cells' centres with align_corners=True
        g = (p - origin) / self.resolution / cells * 2 - 1
        flat = g.reshape(1, -1, *([1] * (d - 1)), d)
        grid = self.values[None, None]
        out = F.grid_sample(grid, flat, mode="bilinear", padding_mode="border", align_corners=True)
        out = out.reshape(points.shape[:-1])
        inside = ((g >= -1) & (g <= 1)).all(-1)
        return torch.where(inside, out, torch.full_like(out, self.outside))
