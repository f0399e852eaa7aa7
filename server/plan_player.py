"""The world's plan player: each command's dated plan (:class:`shared.timed_plan.TimedPlan`)
played at every control tick from its first knot's time, in both modes (docs/protocol.md,
"Playing a plan"). A hardware bridge in another language ports it (numpy only besides the plan).
"""

from __future__ import annotations

import numpy as np

from shared.timed_plan import TIME_EPS, TimedPlan


class PlanPlayer:
    """Plays the plans received, each from its first knot's time.

    A plan applies from its ``t0`` on: one that arrives early waits, and the running plan (the
    safe control, before the first) goes on meanwhile: the planner predicted its start state
    assuming exactly that. Waiting plans are queued, not replaced: a planner that answers every
    state with a lead of a step or more would otherwise replace each waiting plan by the next
    before its time came, and none would ever start. A plan that arrives late starts at once, at
    the knot of the current time (its first knots are past).
    """

    def __init__(self) -> None:
        self.active: TimedPlan | None = None
        self.pending: list[TimedPlan] = []

    def receive(self, plan: TimedPlan) -> None:
        # a waiting plan that would start at or after the new one is older news for that time
        self.pending = [p for p in self.pending if p.t0 < plan.t0 - TIME_EPS] + [plan]

    def clear(self) -> None:
        self.active, self.pending = None, []

    def control(self, t: float) -> tuple[np.ndarray | None, TimedPlan | None]:
        """``(ctrl [nu], plan)`` for world time ``t``; ``(None, plan)`` when the plan that should
        hold has run out (the caller applies the safe control), ``(None, None)`` with no plan."""
        started = [p for p in self.pending if t + TIME_EPS >= p.t0]
        if started:
            self.active = started[-1]
            self.pending = self.pending[len(started) :]
        if self.active is None:
            return None, None
        return self.active.at(t), self.active
