"""A control sequence indexed by world time, played between planner updates.

A planner slower than the world's control loop (the normal case for an arm at 100 Hz-1 kHz)
sends, with each command, the whole control sequence it planned and the world time its first
control is meant for. The world (or a hardware bridge) plays it: at every control tick it applies
the knot whose interval holds the current time, **zero-order hold** (each knot held for ``dt``,
exactly as the planner's rollouts held it), and switches to a newer plan when the time its first
knot is meant for arrives. When the newest plan runs out, the safe control takes over.

Pure functions; no sockets. The world's player is :class:`server.plan_player.PlanPlayer`, the
planner's prediction of what it plays :func:`planner_client.timing.playing`.
``docs/protocol.md`` ("Playing a plan").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

TIME_EPS = 1e-9  # world times are sums of float timesteps: a knot boundary must not fall off by one


@dataclass(frozen=True)
class TimedPlan:
    """Controls ``ctrl [H, nu]``; knot i holds over world time [t0 + i·dt, t0 + (i+1)·dt).

    ``seq`` is the state the plan answers (the world uses it for the plan's age). A command
    without a plan is the one-knot plan of its ``ctrl`` with ``dt = inf``: held from ``t0`` on.
    """

    t0: float
    dt: float
    ctrl: np.ndarray
    seq: int = 0

    def __post_init__(self) -> None:
        if not (self.dt > 0 and math.isfinite(self.t0)):
            raise ValueError(f"plan needs a finite t0 and dt > 0, got t0={self.t0}, dt={self.dt}")
        if self.ctrl.ndim != 2 or self.ctrl.shape[0] < 1:
            raise ValueError(f"plan ctrl must be [H >= 1, nu], got shape {list(self.ctrl.shape)}")

    @property
    def end(self) -> float:
        """World time at which the last knot's interval ends."""
        return self.t0 + self.ctrl.shape[0] * self.dt

    def index(self, t: float) -> int | None:
        """The knot holding at world time ``t``; None before ``t0`` or from :attr:`end` on."""
        if t + TIME_EPS < self.t0:
            return None
        # total for any float: a quotient too large for the plan (an overflow to inf from a tiny
        # dt or a huge span) is past its end, and so is NaN (t = inf of a held plan, t = NaN)
        k = (t - self.t0) / self.dt + TIME_EPS
        return int(k) if k < self.ctrl.shape[0] else None

    def at(self, t: float) -> np.ndarray | None:
        """Zero-order hold: ``ctrl [nu]`` at world time ``t``, or None outside the plan."""
        i = self.index(t)
        return None if i is None else self.ctrl[i]


def held(ctrl: np.ndarray, t: float, seq: int = 0) -> TimedPlan:
    """A command without a plan, as a world plays it: ``ctrl [nu]`` from ``t`` on."""
    return TimedPlan(t, math.inf, np.asarray(ctrl)[None], seq)


def mean_hz(plan_times: Sequence[float]) -> float:
    """Planner iterations per second, as both the planner and the world report it: 1 / mean
    planning time (0 when nothing was planned)."""
    times = [t for t in plan_times if t > 0]
    return 1.0 / float(np.mean(times)) if times else 0.0
