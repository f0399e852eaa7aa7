"""Where a figure was measured: the machine and the library versions, recorded with every
results row. A lock-step episode repeats exactly on one machine with one set of libraries, and
only there: another CPU or another MuJoCo patch release rounds differently."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path

# the libraries whose arithmetic decides an episode's digits
LIBRARIES = ("mujoco", "torch", "numpy")


def machine() -> str:
    """The CPU model and core count, e.g. ``"AMD EPYC, 2 cores"``."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores"


def versions() -> str:
    """The installed versions of :data:`LIBRARIES`, e.g. ``"mujoco 4.0.1, torch 2.13.0+cpu,
    numpy 2.4.6"`` (``-`` for one that is not installed)."""
    out = []
    for name in LIBRARIES:
        try:
            out.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            out.append(f"{name} -")
    return ", ".join(out)
