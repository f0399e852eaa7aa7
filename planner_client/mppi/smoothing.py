"""Savitzky-Golay smoothing of control sequences over the horizon (thesis Alg. 2 line 33, "SGF"),
and the planners' finishing of their means with it: smoothing, projection onto the bounds and,
fused into the same product, the warm-start shift.

The filter is linear, so it is a precomputed ``[T, T]`` matrix: interior rows hold the centred
window coefficients; the first and last half-window rows evaluate the polynomial fitted to the
first / last full window at their own position (``scipy.signal.savgol_filter(mode="interp")``),
which keeps the ends unbiased instead of padding them with invented values.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .bounds import Box
from .cache import cached_table
from .config import MPPIConfig
from .shift import shift_index


def savgol_matrix(horizon: int, window: int, order: int) -> np.ndarray:
    """``[T, T]`` matrix M with ``smoothed = M @ U`` for ``U`` of shape ``[T, nu]``."""

    def compute() -> np.ndarray:
        from scipy.signal import savgol_coeffs

        m = np.zeros((horizon, horizon))
        half = window // 2
        for t in range(horizon):
            start = min(max(t - half, 0), horizon - window)
            m[t, start : start + window] = savgol_coeffs(window, order, pos=t - start, use="dot")
        return m

    return cached_table(f"savgol-T{horizon}-w{window}-p{order}", (horizon, horizon), compute)


def smooth(matrix: Tensor, u: Tensor) -> Tensor:
    """Applies a ``[T, T]`` smoothing matrix to ``[..., T, nu]`` sequences along T (one
    broadcast matrix product over the leading dimensions)."""
    return matrix @ u


def smooth_shift_matrix(
    savgol: Tensor | None, horizon: int, nu: int, dtype: torch.dtype, device: torch.device
) -> Tensor:
    """``[T·nu, 2·T·nu]``: a mean sequence flattened to ``[T·nu]`` (step-major) times it is the
    sequence smoothed by ``savgol [T, T]`` (none: unchanged), then that smoothed sequence
    shifted by one step as :func:`~.shift.shift` does (the last step repeated). The update
    smooths its new means and shifts them for the next iteration in this one product instead
    of a batched product and an index per sequence."""
    eye = torch.eye(horizon, dtype=dtype, device=device)
    smooth_m = eye if savgol is None else savgol  # [T, T]
    lo_idx, _ = shift_index(horizon, 1, device)
    steps = torch.cat([smooth_m, smooth_m.index_select(0, lo_idx)])  # [2T, T]
    return torch.kron(steps, torch.eye(nu, dtype=dtype, device=device)).T.contiguous()


class Smoothing:
    """A planner's finishing of its new means (thesis Alg. 2 line 33): Savitzky-Golay
    smoothing along T when the config asks for it, then projection onto the bounds, which
    smoothing can overshoot; alone, or fused with the one-step shift of the warm start."""

    def __init__(self, cfg: MPPIConfig, box: Box, dtype: torch.dtype, device: torch.device):
        t = cfg.horizon
        self.horizon, self.nu, self.box = t, cfg.nu, box
        self.savgol = (
            torch.as_tensor(
                savgol_matrix(t, cfg.savgol_window, cfg.savgol_order), dtype=dtype, device=device
            )
            if cfg.savgol_window
            else None
        )  # [T, T]
        self.smooth_shift = smooth_shift_matrix(self.savgol, t, cfg.nu, dtype, device)
        if box.active:
            self.flat_lo, self.flat_hi = box.lo.repeat(2 * t), box.hi.repeat(2 * t)

    def __call__(self, u: Tensor) -> Tensor:
        """SGF then projection onto the bounds, ``[..., T, nu]``."""
        if self.savgol is not None:
            u = smooth(self.savgol, u)
        return self.box.project(u)

    def and_shift(self, flat: Tensor) -> tuple[Tensor, Tensor]:
        """The finished means of flat means ``[M, T·nu]``, ``[M, T, nu]``, and the same
        shifted by one step (:func:`~.shift.shift`): one product with :attr:`smooth_shift` and
        one clamp (the projection commutes with a whole-step shift, a selection of steps)."""
        both = flat @ self.smooth_shift
        if self.box.active:
            torch.clamp(both, self.flat_lo, self.flat_hi, out=both)
        return both.view(flat.shape[0], 2, self.horizon, self.nu).unbind(1)
