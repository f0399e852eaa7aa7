"""A disk cache for the sampler's deterministic tables (Halton points, spline bases).

Both are pure functions of a few integers and SciPy's version, and importing ``scipy.stats``
and ``scipy.interpolate`` to compute them costs a planner ~0.6 s at every start (half its start
beyond torch). A table is computed once per machine and read back as a plain ``.npy`` file
(never pickle). The cache is ``$XDG_CACHE_HOME/m3p2i`` (default ``~/.cache/m3p2i``), or
``$M3P2I_CACHE`` when set; a cache that cannot be written, or a file that does not read back
as the expected array, only costs the computation.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np


def cache_dir() -> Path:
    if os.environ.get("M3P2I_CACHE"):
        return Path(os.environ["M3P2I_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "m3p2i"


def cached_table(
    name: str, shape: tuple[int, ...], compute: Callable[[], np.ndarray]
) -> np.ndarray:
    """``compute()`` (a float64 array of ``shape``, a pure function of ``name``), read from the
    cache when there; ``name`` must say everything the result depends on."""
    import scipy  # its version is part of the key (scipy's own __init__ is light)

    path = cache_dir() / f"{name}-scipy{scipy.__version__}.npy"
    try:
        table = np.load(path, allow_pickle=False)
        if table.shape == shape and table.dtype == np.float64:
            return table
    except (OSError, ValueError):
        pass
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
