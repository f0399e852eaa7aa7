"""Control bounds ``[u_min, u_max]``: the map g that brings samples into the box (clamp or
tanh squash), and the projection of means that smoothing pushed past it."""

from __future__ import annotations

import torch
from torch import Tensor

from .config import MPPIConfig


class Box:
    """Control bounds of a config: sample bounding (clamp or squash) and projection.

    Attributes:
        active: whether the config has bounds; without, both maps are the identity.
        squash: whether samples are squashed (tanh) rather than clamped.
        lo, hi: ``[nu]`` bounds (only when active).
        mid, half: ``[nu]`` centre and half-width of the box (only when active).
    """

    def __init__(self, cfg: MPPIConfig, dtype: torch.dtype, device: torch.device):
        self.active = cfg.u_min is not None
        self.squash = cfg.bound == "squash"
        if self.active:
            self.lo = torch.tensor(cfg.u_min, dtype=dtype, device=device)
            self.hi = torch.tensor(cfg.u_max, dtype=dtype, device=device)
            self.mid = 0.5 * (self.hi + self.lo)
            self.half = 0.5 * (self.hi - self.lo)

    def bound(self, v: Tensor) -> Tensor:
        """Brings samples ``[..., nu]`` into the box, in place."""
        if not self.active:
            return v
        if self.squash:
            return v.sub_(self.mid).div_(self.half).tanh_().mul_(self.half).add_(self.mid)
        return torch.clamp(v, self.lo, self.hi, out=v)

    def project(self, v: Tensor) -> Tensor:
        """Clamps means ``[..., nu]`` (smoothing can overshoot a bound)."""
        return torch.clamp(v, self.lo, self.hi) if self.active else v
