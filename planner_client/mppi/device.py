"""The planner's device and its host: moving the few arrays an update weighs in NumPy
(``temperature.weigh``) between them, and the finiteness checks.

On the CPU these share memory with the tensors instead of copying them, and skip torch's
dispatch where NumPy does the same in a fraction of the time: an update makes a handful of
such calls, each of which used to cost more than the arithmetic it moves.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor


class Device:
    """The dtype and device of every tensor a planner makes, and its host transfers."""

    def __init__(self, dtype: torch.dtype, device: str | torch.device):
        self.dtype = dtype
        self.device = torch.device(device)
        self.cpu = self.device.type == "cpu"

    def tensor(self, x: np.ndarray) -> Tensor:
        """A host array of the weighting as a tensor of the planner's dtype and device; on the
        CPU in float64 the same memory (``from_numpy`` takes a microsecond, ``as_tensor`` with
        a dtype and device nine)."""
        if self.cpu and x.dtype == np.float64 and self.dtype == torch.float64:
            return torch.from_numpy(x)
        return torch.as_tensor(x, dtype=self.dtype, device=self.device)

    def host(self, x: Tensor) -> np.ndarray:
        """``x`` on the host as NumPy; on the CPU the same memory, without ``cpu()``'s call."""
        return x.numpy() if self.cpu else x.cpu().numpy()

    def rows(self, x: np.ndarray) -> Tensor:
        """Host row indices ``x`` (int64) as an index tensor on the planner's device."""
        t = torch.from_numpy(x)
        return t if self.cpu else t.to(self.device)

    def finite(self, x: Tensor) -> bool:
        """Whether ``x`` holds no NaN or inf (its sum is finite); on the CPU summed by NumPy
        over the same memory (a third of torch's select, sum and transfer after a rollout)."""
        if self.cpu:
            return math.isfinite(x.numpy().sum())
        return math.isfinite(float(x.sum()))

    def finite_row(self, x: Tensor, i: int) -> bool:
        """:meth:`finite` of ``x[i]``, on the CPU without torch's select."""
        if self.cpu:
            return math.isfinite(x.numpy()[i].sum())
        return math.isfinite(float(x[i].sum()))

    def zeros(self, *shape: int) -> Tensor:
        """Zeros of the planner's dtype on its device."""
        return torch.zeros(*shape, dtype=self.dtype, device=self.device)

    def step_costs(self, step_costs: Tensor, shape: tuple[int, int]) -> Tensor:
        """The caller's per-step costs, checked to be ``shape`` ``[S, T]``, in the planner's
        dtype and on its device (unconverted when they already are)."""
        if tuple(step_costs.shape) != shape:
            raise ValueError(
                f"step_costs must have shape {shape} [S, T], got {tuple(step_costs.shape)}"
            )
        if step_costs.dtype == self.dtype and step_costs.device == self.device:
            return step_costs
        return step_costs.to(dtype=self.dtype, device=self.device)
