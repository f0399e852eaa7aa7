"""Savitzky-Golay smoothing of control sequences over the horizon (thesis Alg. 2 line 33, "SGF").

The filter is linear, so it is a precomputed ``[T, T]`` matrix: interior rows hold the centred
window coefficients; the first and last half-window rows evaluate the polynomial fitted to the
first / last full window at their own position (``scipy.signal.savgol_filter(mode="interp")``),
which keeps the ends unbiased instead of padding them with invented values.
"""

from __future__ import annotations

import numpy as np
from torch import Tensor

from .cache import cached_table


def savgol_matrix(horizon: int, window: int, order: int) -> np.ndarray:
    """``[T, T]`` matrix M with ``smoothed = M @ U`` for ``U`` of shape ``[T, nu]``."""
    def compute() -> np.ndarray:
        from scipy.signal import savgol_coeffs
        m = np.zeros((horizon, horizon))
        half = window // 2
        for t in range(horizon):
            start = min(max(t - half, 0), horizon - window)
            m[t, start:start + window] = savgol_coeffs(window, order, pos=t - start, use="dot")
        return m
    return cached_table(f"savgol-T{horizon}-w{window}-p{order}", (horizon, horizon), compute)


def smooth(matrix: Tensor, u: Tensor) -> Tensor:
    """Applies a ``[T, T]`` smoothing matrix to ``[..., T, nu]`` sequences along T (one
    broadcast matrix product over the leading dimensions)."""
    return matrix @ u
