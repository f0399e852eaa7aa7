"""Where M3P2I's modes sit in the ``[S]`` sample rows, and what each pins: the modes'
validation, their row layout, pinned channels and null actions."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from .bounds import Box
from .config import ModeSpec, MPPIConfig
from .device import Device


@dataclass(frozen=True)
class ModeLayout:
    """N modes' samples grouped by mode, in mode order, in the rows of ``[S]``.

    Pinning is ``v·pin_keep + pin_value`` (``pin_keep`` 0 on pinned channels), exact for finite
    v; with clamp bounds, or pins and no bounds, ``clamp`` does bounds and pins in one kernel.
    """

    slices: list[slice]  # [N] rows of each mode
    starts: list[int]  # [N] first row of each mode (slices' starts)
    row_mode: Tensor  # [S] mode of each sample row
    first: Tensor  # [N] first row of each mode
    last: Tensor  # [N] last row of each mode
    null: Tensor  # [N, T, nu] each mode's null action: zero, bounded, pinned
    pin_keep: Tensor | None  # [S, 1, nu] 0 on pinned channels, 1 elsewhere; None: no pins
    pin_value: Tensor  # [S, 1, nu] pinned values, 0 elsewhere
    clamp: tuple[Tensor, Tensor] | None  # [S, 1, nu] lo and hi, lo = hi = value where pinned

    @staticmethod
    def build(modes: Sequence[ModeSpec], cfg: MPPIConfig, box: Box, dev: Device) -> ModeLayout:
        """The layout of ``modes`` (validated first: raises ``ValueError``)."""
        check_modes(modes, cfg)
        counts = [m.samples for m in modes]
        s = sum(counts)
        starts = np.cumsum([0, *counts])[:-1]
        k = torch.tensor(counts, device=dev.device)
        first = torch.as_tensor(starts, device=dev.device)
        last = first + k - 1
        keep = torch.ones(s, 1, cfg.nu, dtype=dev.dtype, device=dev.device)
        value = torch.zeros_like(keep)
        slices = [slice(int(a), int(a) + n) for a, n in zip(starts, counts)]
        for m, rows in zip(modes, slices):
            for ch, val in m.fixed.items():
                keep[rows, :, ch] = 0.0
                value[rows, :, ch] = val
        pinned = keep == 0
        pin_keep = keep if bool(pinned.any()) else None
        clamp = None
        if not box.squash and (box.active or pin_keep is not None):
            inf = torch.full_like(keep, math.inf)
            lo, hi = (box.lo, box.hi) if box.active else (-inf, inf)
            clamp = (torch.where(pinned, value, lo), torch.where(pinned, value, hi))
        row_mode = torch.repeat_interleave(torch.arange(len(counts), device=dev.device), k)
        null = box.project(dev.zeros(len(modes), cfg.horizon, cfg.nu)) * keep[last] + value[last]
        return ModeLayout(
            slices=slices,
            starts=[int(a) for a in starts],
            row_mode=row_mode,
            first=first,
            last=last,
            null=null,
            pin_keep=pin_keep,
            pin_value=value,
            clamp=clamp,
        )


def check_modes(modes: Sequence[ModeSpec], cfg: MPPIConfig) -> None:
    """Raises ``ValueError`` unless ``modes`` are at least one, uniquely named, each with more
    samples than its extra rows and η_l, and fixed channels inside ``0..nu - 1``."""
    if not modes:
        raise ValueError("M3P2I needs at least one mode")
    if len({m.name for m in modes}) != len(modes):
        raise ValueError(f"mode names must be unique, got {[m.name for m in modes]}")
    extra = cfg.null_action + cfg.keep_best
    for m in modes:
        if m.samples < 1 + extra:
            raise ValueError(f"mode {m.name!r}: needs more than {extra} samples, got {m.samples}")
        bad = [ch for ch in m.fixed if not 0 <= ch < cfg.nu]
        if bad:
            raise ValueError(f"mode {m.name!r}: fixed channels {bad} outside 0..{cfg.nu - 1}")
        # η_i (paper Eq. 6) counts the samples that carry weight, so η_i ≤ K_i: a window above
        # it is never met, and adaptation would drive λ_i to its largest value every iteration.
        # η_l = K_i is allowed (approached as λ grows). The fused row has S ≥ K_i samples.
        if cfg.eta_bounds is not None and cfg.eta_bounds[0] > m.samples:
            raise ValueError(
                f"mode {m.name!r}: {m.samples} samples cannot reach the eta window "
                f"{tuple(cfg.eta_bounds)}: eta counts the samples that carry "
                f"weight, so eta_l must be <= {m.samples}"
            )
