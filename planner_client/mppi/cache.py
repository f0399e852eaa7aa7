"""A disk cache for the sampler's deterministic tables (Halton points, spline bases).

Both are pure functions of a few integers and SciPy's version, and importing ``scipy.stats``
and ``scipy.interpolate`` to compute them costs a planner ~0.6 s at every start (half its start
beyond torch). A table is computed once per machine and read back as a plain ``.npy`` file
(never pickle). The cache is ``$XDG_CACHE_HOME/m3p2i`` (default ``~/.cache/m3p2i``), or
``$M3P2I_CACHE`` when set; a cache that cannot be written, or a file that does not read back
as the expected array, only costs the computation.
"""

from __future__ import annotations

import glob
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np


def cache_dir() -> Path:
    if os.environ.get("M3P2I_CACHE"):
        return Path(os.environ["M3P2I_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "m3p2i"


def _path(name: str) -> Path:
    import scipy  # its version is part of the key (scipy's own __init__ is light)

    return cache_dir() / f"{name}-scipy{scipy.__version__}.npy"


def _read(path: Path, shape: tuple[int, ...]) -> np.ndarray | None:
    try:
        table = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        return None
    return table if table.shape == shape and table.dtype == np.float64 else None


def cached_table(
    name: str, shape: tuple[int, ...], compute: Callable[[], np.ndarray]
) -> np.ndarray:
    """``compute()`` (a float64 array of ``shape``, a pure function of ``name``), read from the
    cache when there; ``name`` must say everything the result depends on."""
    path = _path(name)
    table = _read(path, shape)
    if table is not None:
        return table
    table = np.ascontiguousarray(compute(), dtype=np.float64)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # written whole then renamed: planners starting together never read half a file
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npy", delete=False) as f:
            np.save(f, table, allow_pickle=False)
        os.replace(f.name, path)
    except OSError:
        pass
    return table


def cached_prefix(
    template: str,
    rows: int,
    width: int,
    compute: Callable[[], np.ndarray],
    longer_fits: Callable[[int], bool] = lambda rows: True,
) -> np.ndarray:
    """:func:`cached_table` ``template.format(rows)`` of shape ``[rows, width]``, for a table whose
    first rows do not depend on how many it has (a Halton sequence's first points; a spline basis's
    first steps over the same knots: ``longer_fits(n)`` says whether ``n`` rows have them). On a
    miss, the first rows of a longer table already cached are read instead of computing: the
    anytime planner changes its samples and horizon in real time, where importing SciPy to compute
    a table would stall an iteration for half a second (the values are the same, bit for bit)."""
    exact = _read(_path(template.format(rows)), (rows, width))
    if exact is not None:
        return exact
    head, tail = _path(template.format("\0")).name.split("\0")
    for path in cache_dir().glob(f"{glob.escape(head)}*{glob.escape(tail)}"):
        count = path.name[len(head) : -len(tail)]
        if count.isdigit() and int(count) > rows and longer_fits(int(count)):
            longer = _read(path, (int(count), width))
            if longer is not None:
                return np.ascontiguousarray(longer[:rows])
    return cached_table(template.format(rows), (rows, width), compute)
