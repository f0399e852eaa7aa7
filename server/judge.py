"""The scenario's episode test: success (held for ``episode.hold``) or time-out, judged on the
world's state in the scenario model's coordinates, and the success predicates' measures.

Shared by the simulated world and by bridges, which judge the measured state the same way.
"""

from __future__ import annotations

import mujoco

from shared.frames import FrameResolver
from shared.predicates import WorldView
from shared.scenario import Scenario


class EpisodeJudge:
    """``episode.success`` bound to a model; :meth:`update` after every step."""

    def __init__(self, scenario: Scenario, resolve: FrameResolver):
        self.success_test = [p.bind(resolve) for p in scenario.episode.success]
        self.hold = scenario.episode.hold
        self.max_time = scenario.episode.max_time
        self.reset()

    def reset(self) -> None:
        self._success_since: float | None = None

    def update(
        self, status: str, data: mujoco.MjData, extras: dict[str, float], time: float
    ) -> str:
        """The status after a step at world ``time`` (``data``'s kinematics up to date):
        ``success`` once the predicates held for ``hold`` seconds without a break (a stack that
        topples, or a cube moved off its goal, is no success yet), ``timeout`` at
        ``max_time``; an ended episode keeps its status."""
        if status != "running":
            return status
        view = WorldView(data, extras)
        if not all(p(view) for p in self.success_test):
            self._success_since = None
        elif self._success_since is None:
            self._success_since = time
        if self._success_since is not None and time - self._success_since >= self.hold - 1e-9:
            return "success"
        if time >= self.max_time - 1e-9:
            return "timeout"
        return status

    def measures(self, data: mujoco.MjData, extras: dict[str, float]) -> dict[str, float]:
        """The success predicates' measures (e.g. the final distance to the goal)."""
        view = WorldView(data, extras)
        out: dict[str, float] = {}
        for p in self.success_test:
            out.update(p.measures(view))
        return out
