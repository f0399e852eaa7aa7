"""The cells rays cross, found for all rays of a scan at once: each ray is sampled every half
cell from where it enters the grid to where it ends or leaves it, and every sample's cell is
marked. Vectorised in numpy (no Python loop per ray); works for 2-D and 3-D grids alike.

A cell a ray crosses for half a cell or more always holds one of its samples; one whose corner
it only grazes may hold none and be left as it was. That is the usual trade of sampled ray
casting for speed, and a map updated by many rays from moving sensors does not notice it.
"""

from __future__ import annotations

import numpy as np

from planner_client.perception.grid import GridSpec

# samples computed at once: their int32 temporaries stay in the processor's cache (measured:
# 2**17 samples twice as fast as 2**23) and numpy's per-call overhead is still small
CHUNK_SAMPLES = 1 << 17
# fixed-point positions, in cells with 16 fractional bits: a coordinate stays below 2**31 on
# grids of up to MAX_CELLS a side (GridSpec checks it); the rounded step drifts by at most
# 2**-17 cell a sample, < 0.01 cell across a grid of 1000 cells
_BITS = 16
_ONE = 1 << _BITS


def entry_exit(
    spec: GridSpec, origin: np.ndarray, dirs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where rays ``origin [d] + t · dirs [M, d]`` enter and leave the grid's box: ``t0, t1
    [M]`` (m along unit directions; ``t0 >= t1`` for a ray that misses it; ``t0`` may be
    negative when the origin is inside)."""
    lo, hi = spec.bounds
    # a zero component would divide by zero: a tiny one gives huge t of one sign instead, which
    # is the same answer (inside that slab for all t, or never)
    d = np.where(np.abs(dirs) < 1e-12, 1e-12, dirs)
    a, b = (lo - origin) / d, (hi - origin) / d
    return np.minimum(a, b).max(axis=1), np.maximum(a, b).min(axis=1)


def crossed(spec: GridSpec, origin: np.ndarray, dirs: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which cells the rays ``origin [d] + t · dirs [M, d]``, ``0 <= t < ends [M]`` (unit
    directions, m) cross: a flat bool mask ``[prod(spec.shape)]`` (C order)."""
    step = spec.resolution / 2
    t0, t1 = entry_exit(spec, origin, dirs)
    t0 = np.maximum(t0, 0.0)
    n = np.ceil((np.minimum(t1, ends) - t0) / step).astype(np.int64)
    keep = n > 0
    # rays sorted by their number of samples, taken in chunks padded to the longest in each:
    # broadcasting [rays, samples] beats gathering per sample, and sorting keeps the padding
    # small (a padded sample repeats its ray's last one, which marks nothing new)
    order = np.argsort(n[keep], kind="stable")
    n, t0, dirs = n[keep][order], t0[keep][order], dirs[keep][order]
    # positions in cells as fixed-point int32 (integer adds and a shift instead of float
    # rounding: three times faster): each ray's first sample and its step, both rounded. The
    # mask has a border of one cell: a sample on the box's face that rounds out of it lands
    # there (cheaper than clipping every sample), and the border is cut off at the end.
    cells = (origin - np.asarray(spec.origin)) / spec.resolution + 1.0  # + 1: the border
    first = np.rint((cells + t0[:, None] * dirs / spec.resolution) * _ONE).astype(np.int32)
    first += _ONE // 2  # the shift floors: + 1/2 rounds to the nearest cell
    stride = np.rint(dirs * (0.5 * _ONE)).astype(np.int32)  # half a cell along the ray
    padded = np.zeros(tuple(v + 2 for v in spec.shape), dtype=bool)
    flat_mask = padded.reshape(-1)
    strides = np.array(padded.strides[::-1]) // padded.itemsize  # x, y[, z]
    rows = max(1, CHUNK_SAMPLES // int(n[-1])) if n.size else 1
    for i in range(0, n.size, rows):
        j = min(i + rows, n.size)
        k = np.minimum(np.arange(n[j - 1], dtype=np.int32), (n[i:j] - 1).astype(np.int32)[:, None])
        flat_mask[_cells(k, first[i:j], stride[i:j], strides)] = True
    return padded[(slice(1, -1),) * spec.dims].reshape(-1)


def _cells(k: np.ndarray, first: np.ndarray, stride: np.ndarray, strides: np.ndarray) -> np.ndarray:
    """Flat cell indices ``[rows, width]`` of samples ``k`` (their numbers along each ray) of
    rays starting at fixed-point cells ``first [rows, d]`` and moving ``stride [rows, d]``
    (``strides [d]``: the flat index's step per cell along x, y[, z])."""
    flat = np.zeros(k.shape, dtype=np.int32)
    tmp = np.empty(k.shape, dtype=np.int32)
    for a, cell_stride in enumerate(strides):
        np.multiply(k, stride[:, a, None], out=tmp)
        tmp += first[:, a, None]
        np.right_shift(tmp, _BITS, out=tmp)
        tmp *= cell_stride
        flat += tmp
    return flat
