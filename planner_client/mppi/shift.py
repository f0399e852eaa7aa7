"""The warm start (thesis Alg. 2 lines 36-39, paper Alg. 4 lines 10, 29): a sequence moved
some control steps later, for the next iteration to sample around."""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor


def shift(seq: Tensor, steps: float = 1.0) -> Tensor:
    """Warm start ``steps`` control steps later, ``[..., T, nu] -> [..., T, nu]``.

    New step t is the old sequence at t + steps: linearly interpolated between steps for a
    fractional shift, the last step repeated past the end and the first held before the start
    (a negative shift). Repeating (as the thesis code does) keeps a constant command going at the
    end of the horizon; a zero would brake velocity-controlled robots in every fresh plan tail.
    An integer shift is an exact copy of the kept steps.
    """
    horizon = seq.shape[-2]
    if not math.isfinite(steps):
        raise ValueError(f"shift by {steps} steps: expected a finite number")
    # a shift past either end keeps only the held end step: beyond the horizon every shift is
    # the same, so a huge one (a world time far off) is clamped before it becomes an index
    steps = min(max(steps, -float(horizon)), float(horizon))
    whole = math.floor(steps)
    frac = steps - whole
    lo_idx, hi_idx = shift_index(horizon, whole, seq.device)
    lo = seq.index_select(-2, lo_idx)
    if frac == 0.0:
        return lo
    return torch.lerp(lo, seq.index_select(-2, hi_idx), frac)


@functools.lru_cache(maxsize=64)
def shift_index(horizon: int, whole: int, device: torch.device) -> tuple[Tensor, Tensor]:
    """``[T]`` rows ``t + whole`` and ``t + whole + 1`` clamped into the horizon, for
    :func:`shift`: made once, as the planner shifts three sequences by one step every iteration
    (read-only: ``index_select`` never writes its index)."""
    idx = torch.arange(horizon, device=device) + whole
    return idx.clamp(0, horizon - 1), (idx + 1).clamp(0, horizon - 1)
