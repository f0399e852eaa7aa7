"""A team's plans in one world: each robot plays its own planner's newest plan.

The world's control vector is the robots' controls side by side (shared/scenario/team.py); a
robot whose plan ran out, or whose planner went quiet (:meth:`TeamPlayer.clear`), is held on its
own safe control while the others play on. Each robot's newest plan is forwarded to the other
planners with every state (``state.plans``, protocol 4), so that each rolls the others out
along what they said they would do.
"""

from __future__ import annotations

import numpy as np

from server.plan_player import PlanPlayer
from shared import protocol as P
from shared.scenario import Scenario
from shared.timed_plan import TimedPlan


class TeamPlayer:
    """A :class:`~server.plan_player.PlanPlayer` per robot of ``scenario.team``."""

    def __init__(self, scenario: Scenario):
        self.team = scenario.team
        self.players = {m.name: PlanPlayer() for m in self.team}
        self.newest: dict[str, TimedPlan] = {}
        self.slices, start = {}, 0
        for m in self.team:
            nu = len(m.robot.spec.ctrl_names)
            self.slices[m.name] = slice(start, start + nu)
            start += nu

    def receive(self, plan: TimedPlan, robot: str) -> None:
        """Robot ``robot``'s plan, played from its ``t0`` on and forwarded to the others."""
        self.players[robot].receive(plan)
        self.newest[robot] = plan

    def clear(self, robot: str | None = None) -> None:
        """Forget ``robot``'s plans (all robots' with None): it is held on its safe control."""
        for name in [robot] if robot is not None else list(self.players):
            self.players[name].clear()
            self.newest.pop(name, None)

    def control(self, t: float, last: np.ndarray) -> tuple[np.ndarray | None, TimedPlan | None]:
        """``(ctrl [nu], plan)`` for world time ``t``: each robot's plan's knot, or its safe stop
        (its ``hold_ctrl`` at ``last``, the world's last control); ``plan`` is the oldest of the
        plans playing (the step's age is the oldest robot's). ``(None, plan)`` when no robot
        has a plan playing: the world's safe control."""
        parts, playing, ended = [], [], None
        for m in self.team:
            ctrl, plan = self.players[m.name].control(t)
            sl = self.slices[m.name]
            if ctrl is None:
                ended = plan or ended
                ctrl = m.robot.spec.safe_stop(last[sl])
            else:
                playing.append(plan)
            parts.append(np.asarray(ctrl, dtype=float))
        if not playing:
            return None, ended
        return np.concatenate(parts), min(playing, key=lambda p: p.seq)

    def forwarded(self) -> list[P.RobotPlan]:
        """Every robot's newest plan with a finite step, as a state carries them."""
        return [
            P.RobotPlan(robot=name, t0=p.t0, dt=p.dt, ctrl=p.ctrl)
            for name, p in self.newest.items()
            if np.isfinite(p.dt)
        ]
