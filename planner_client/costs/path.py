"""Cost terms that follow the scenario's guide (``guide:``; planner_client/guide.py): the path
length left to the goal and the distance from the path, of a frame at every rollout step. The
guide's sub-goal is a frame, ``site:guide``, that any term can name instead (e.g. ``distance``
to it). Every term returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass, field

from planner_client.costs.base import CostTerm, register
from planner_client.costs.helpers import norm
from planner_client.guide import GuideState, handle_target, project
from planner_client.sensors import SensorRequest


def _guide(s, ctx) -> GuideState:
    if ctx.guide is None:
        raise s.error(
            "term",
            "follows the scenario's guide, and it has none",
            s.data["term"],
            "a guide: key in the scenario (docs/scenarios.md)",
        )
    return ctx.guide


@register("guide_progress")
@dataclass
class GuideProgress(CostTerm):
    """The guide's path length (m) left from the nearest point on it of frame ``a`` (default:
    the guided body) to the goal, at every rollout step: a distance to the goal that goes round
    the obstacles, with no local minimum in front of a U. Without a path (none yet, or the
    guide blocked): the straight distance to the goal. xy only."""

    a: str
    guide: GuideState = field(repr=False)

    @classmethod
    def from_params(cls, s, ctx):
        guide = _guide(s, ctx)
        return cls(a=ctx.frame(s, "a", guide.cfg.for_), guide=guide)

    def sensors(self):
        return [SensorRequest("framepos", self.a)]

    def __call__(self, batch):
        return project(batch.get(self.requests[0])[..., :2], self.guide.path)[1]


@register("guide_distance")
@dataclass
class GuideDistance(GuideProgress):
    """Distance (m) of frame ``a`` (default: the guided body) from the guide's path, at every
    rollout step: keeps a body in the corridor the path found. 0 without a path. xy only."""

    def __call__(self, batch):
        return project(batch.get(self.requests[0])[..., :2], self.guide.path)[0]


@register("guide_handle")
@dataclass
class GuideHandle(CostTerm):
    """Distance (m, xy) of the robot frame ``a`` (default ``robot``) from its place beside the
    guided object ``obj`` (default: the guide's body) at every rollout step: behind the object
    along the path for a push, ahead of it, at its side or behind it for a pull, as the guide's
    ``room`` found clear of the obstacles (the place of the path cell nearest to the object).
    Replaces S_dist(R, O) (paper Eq. 14) where the robot must go round the object first, e.g.
    to get behind a box that it dragged out of a corner. Without a path: |x_a - x_obj|."""

    a: str
    obj: str
    guide: GuideState = field(repr=False)

    @classmethod
    def from_params(cls, s, ctx):
        guide = _guide(s, ctx)
        if guide.cfg.room == "none":
            raise s.error(
                "term",
                "needs a guide with room for the robot",
                "guide_handle",
                "guide.room: push, pull or any",
            )
        return cls(
            a=ctx.frame(s, "a", "robot"), obj=ctx.frame(s, "obj", guide.cfg.for_), guide=guide
        )

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.obj)]

    def __call__(self, batch):
        x_a, x_o = (batch.get(r)[..., :2] for r in self.requests)
        return norm(x_a - handle_target(x_o, self.guide.path))
