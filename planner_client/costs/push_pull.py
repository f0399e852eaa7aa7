"""Cost terms of pushing and pulling an object to a goal: the robot-object-goal alignment and
the pull direction (paper Eqs. 16-21, Sec. III.A). Every term returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from planner_client.costs.base import CostTerm, register
from planner_client.costs.helpers import axes_param, cos_rog, cosine, frame_params, norm
from planner_client.sensors import SensorRequest
from shared.config import positive, string_list
from shared.geometry import select_axes


@register("push_align")
@dataclass
class PushAlign(CostTerm):
    """S_align_push(R, O, G) = f(cos θ_ROG), f = relu (paper Eqs. 16-18).

    0 while the robot R is anywhere behind the object O as seen from the goal G (θ_ROG >= 90°),
    rising to 1 with R between O and G, where a push drives O away from G. Parameters: ``a``
    robot frame, ``obj``, ``goal``; ``axes`` xy (default) or xyz for the angle.
    """

    a: str
    obj: str
    goal: str
    axes: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**frame_params(s, ctx, "a", "obj", "goal"), axes=axes_param(s, "xy"))

    def sensors(self):
        return [SensorRequest("framepos", f) for f in (self.a, self.obj, self.goal)]

    def __call__(self, batch):
        return torch.relu(cos_rog(batch, self.a, self.obj, self.goal, self.axes))


@register("pull_align")
@dataclass
class PullAlign(PushAlign):
    """S_align_pull(R, O, G) = f(-cos θ_ROG), f = relu (paper Eq. 20).

    The mirror of ``push_align``: 0 while the robot R is on the goal's side of the object O
    (where pulling O brings it to G), rising to 1 with R directly behind O. Same parameters.
    """

    def __call__(self, batch):
        return torch.relu(-cos_rog(batch, self.a, self.obj, self.goal, self.axes))


@register("pull_direction")
@dataclass
class PullDirection(CostTerm):
    """S_action_pull(R, O) = f((x_O - x_R)·u / (|x_O - x_R| |u|)), f = relu (paper Eq. 21).

    Penalises sampled controls u that drive the robot R towards the object O: 1 for u straight
    at O, 0 for any u with a component away from it, and 0 for u = 0 (standing still is
    allowed). u is the control channels named by ``actuators`` (world-frame velocities, one per
    axis in ``axes``: xy by default), read from the sampled controls ``[S, T, nu]``.

    ``within`` (metres, optional) counts the term only while |x_O - x_R| <= within, as the
    thesis code does (0.5 m). In the paper pulling starts once the task planner observes the
    robot close to the object (paper Eq. 13); a scenario that pulls without that precondition must
    still let the robot drive up to the object, which paper Eq. 21 alone forbids.
    """

    a: str
    obj: str
    channels: tuple[int, ...]
    axes: str
    within: float | None = None

    @classmethod
    def from_params(cls, s, ctx):
        named = frame_params(s, ctx, "a", "obj")
        axes = axes_param(s, "xy")
        names = s.req("actuators", string_list, "a list of actuator names")
        if len(names) != len(axes):
            raise s.error(
                "actuators",
                f"needs one velocity actuator per axis of {axes!r}",
                list(names),
                f"{len(axes)} actuator names",
            )
        return cls(
            **named,
            channels=ctx.channels(s, "actuators", names),
            axes=axes,
            within=s.opt("within", None, positive, "metres > 0"),
        )

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.obj)]

    def __call__(self, batch):
        x_r, x_o = (batch.get(r) for r in self.requests)
        u = batch.controls[..., list(self.channels)]
        d = select_axes(x_o - x_r, self.axes)
        cost = torch.relu(cosine(d, u))
        if self.within is not None:
            cost = cost * (norm(d) <= self.within)
        return cost
