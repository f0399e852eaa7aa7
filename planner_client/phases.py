"""Where an iteration's time goes: :class:`PhaseClock` sums the seconds of each phase of
:meth:`planner_client.controller.Controller.step` (mirror, estimate, map, guide, task, start,
and inside the motion planner sampling, rollout, costs, update; then command) and, for the
benchmark's split (scripts/benchmark.py), keeps each step's when asked. A mark is one
``perf_counter`` call and a dict add: always on, it costs nothing measurable."""

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
        self._kept: list[dict[str, float]] | None = None  # per step, after keep()

    def start(self) -> None:
        """A step begins."""
        self.steps += 1
        if self._kept is not None:
            self._kept.append({})
        self._last = time.perf_counter()

    def mark(self, phase: str) -> None:
        """``phase`` ended now."""
        now = time.perf_counter()
        self.totals[phase] += now - self._last
        if self._kept:
            step = self._kept[-1]
            step[phase] = step.get(phase, 0.0) + now - self._last
        self._last = now

    def reset(self) -> None:
        """Forget the sums (e.g. after warm-up)."""
        self.totals.clear()
        self.steps = 0

    def keep(self) -> None:
        """Forget the sums and keep each step's phases from the next step on, for
        :meth:`median_ms` (the benchmark: a planner process never keeps them)."""
        self.reset()
        self._kept = []

    def median_ms(self) -> dict[str, float]:
        """Median milliseconds of each phase over the steps kept since :meth:`keep`, in
        :data:`PHASES` order (others after); a step without the phase counts 0. Medians, not
        means: a step a busy virtual machine stalls lands in one phase, and with medians the
        phases add up to about the median step."""
        from statistics import median  # here: the entry point imports this module first

        steps = self._kept or []
        seen = {p for step in steps for p in step}
        order = [p for p in PHASES if p in seen] + sorted(seen.difference(PHASES))
        return {p: median(s.get(p, 0.0) for s in steps) * 1e3 for p in order}

    def report(self) -> str:
        """``name seconds`` per phase, comma-separated: how :data:`STARTUP` is logged."""
        return ", ".join(f"{p} {s:.3f} s" for p, s in self.totals.items())


# The planner process's start-up, from its entry point (planner_client/__main__.py) to its first
# command sent: imports, check, build, handshake, first command; logged once as "start-up: ..."
# (scripts/startup.py reads it). Never started in-process: nothing is logged there.
STARTUP = PhaseClock()
