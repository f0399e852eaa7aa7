"""MuJoCo's warnings in the planner's log: each said once, its repeats counted.

MuJoCo warns about an unstable simulation ("Nan, Inf or huge value in QPOS ...") once per MjData
and then resets it, and the rollouts reset every sample's MjData to the planner's state each
iteration: one hostile state (``qpos`` 1e308, finite, so the protocol takes it) printed the
warning once per sample, hundreds of lines an iteration, straight to standard output (and
MUJOCO_LOG.TXT in the working folder). :func:`count_mujoco_warnings` routes them to the log
instead: the first of each kind in full, then its count at 10, 100, 1000, ... repeats.
"""

from __future__ import annotations

import logging
import re
import threading

import mujoco

log = logging.getLogger("m3p2i.planner")

_TIME = re.compile(r"\s*Time = [^ ]*\.?$")  # the world time MuJoCo appends: not part of the kind


class MujocoWarnings:
    """The callback MuJoCo calls with each warning's text (from the rollouts' threads too):
    counts them by kind (the text without its time) and logs the first of each, then the
    count at each power of ten."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def __call__(self, text: str) -> None:
        kind = _TIME.sub("", text.strip())
        with self._lock:
            n = self.counts[kind] = self.counts.get(kind, 0) + 1
        if n == 1:
            log.warning("MuJoCo: %s (said once: its repeats are counted)", text.strip())
        elif n >= 10 and str(n).strip("0") == "1":  # 10, 100, 1000, ...
            log.warning("MuJoCo warned %d times so far: %s", n, kind)


def count_mujoco_warnings() -> MujocoWarnings:
    """Route this process's MuJoCo warnings to a fresh :class:`MujocoWarnings` (returned)."""
    counter = MujocoWarnings()
    mujoco.set_mju_user_warning(counter)
    return counter
