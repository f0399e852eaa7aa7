"""Where an iteration's time goes: :class:`PhaseClock` sums the seconds of each phase of
:meth:`planner_client.controller.Controller.step` (mirror, estimate, map, guide, task, start,
and inside the motion planner sampling, rollout, costs, update; then command), for the
benchmark's split (scripts/benchmark.py). A mark is one ``perf_counter`` call and a dict add:
always on, it costs nothing measurable."""

from __future__ import annotations

import time
from collections import defaultdict

PHASES = (
    "mirror",  # the state into the planner's model
    "estimate",  # actuation tracking and the model variants' identifier
    "map",  # scans queued, and fused in lock-step
    "guide",  # the global path
    "task",  # observers and active inference: the action and its modes
    "start",  # the plan's start: prediction over the lead
    "sampling",  # M3P2I's perturbed controls [S, T, nu]
    "rollout",  # the batched MuJoCo rollout: sensors [S, T, ·]
    "costs",  # the modes' objectives: [S, T]
    "update",  # weights, the mode fusion and the smoothed plan
    "command",  # the command, the plan's record, statistics
)


class PhaseClock:
    """Seconds per phase summed since :meth:`reset`: :meth:`start` at the top of a step, then
    :meth:`mark` at the end of each phase charges it the time since the previous mark."""

    def __init__(self) -> None:
        self.totals: defaultdict[str, float] = defaultdict(float)
        self.steps = 0
        self._last = 0.0

    def start(self) -> None:
        """A step begins."""
        self.steps += 1
        self._last = time.perf_counter()

    def mark(self, phase: str) -> None:
        """``phase`` ended now."""
        now = time.perf_counter()
        self.totals[phase] += now - self._last
        self._last = now

    def reset(self) -> None:
        """Forget the sums (e.g. after warm-up)."""
        self.totals.clear()
        self.steps = 0

    def report(self) -> str:
        """``name seconds`` per phase, comma-separated: how :data:`STARTUP` is logged."""
        return ", ".join(f"{p} {s:.3f} s" for p, s in self.totals.items())

    def per_step_ms(self) -> dict[str, float]:
        """Mean milliseconds per step of each phase, in :data:`PHASES` order (others after)."""
        n = max(self.steps, 1)
        order = [p for p in PHASES if p in self.totals]
        order += [p for p in self.totals if p not in PHASES]
        return {p: self.totals[p] * 1e3 / n for p in order}


# The planner process's start-up, from its entry point (planner_client/__main__.py) to its first
# command sent: imports, check, build, handshake, first command; logged once as "start-up: ..."
# (scripts/startup.py reads it). Never started in-process: nothing is logged there.
STARTUP = PhaseClock()
