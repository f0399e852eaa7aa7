"""Cost terms on a gripper's opening (paper Eqs. 28, 30). Every term returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass

from planner_client.costs.base import CostTerm, register
from planner_client.costs.helpers import frame_params, norm
from planner_client.sensors import SensorRequest
from shared.config import non_negative, one_of


@register("gripper_width")
@dataclass
class GripperWidth(CostTerm):
    """Gripper opening l = |x_left - x_right| between two frames, e.g. fingertip sites.

    ``target: closed`` gives l (paper Eq. 28, closing to grasp), ``target: open`` gives 1 - l
    (paper Eq. 30, opening to release; l in metres stays far below 1), ``value: w`` gives |l - w|
    (e.g. the cube's width, to hold without squeezing). Exactly one of ``target``/``value``.
    """

    left: str
    right: str
    target: str
    value: float

    @classmethod
    def from_params(cls, s, ctx):
        named = frame_params(s, ctx, "left", "right")
        if s.has("target") == s.has("value"):
            raise s.error(
                "target",
                "give exactly one of target (closed|open) or value (metres)",
                expected="target: closed, target: open or value: <width>",
            )
        if s.has("value"):
            return cls(**named, target="value", value=s.req("value", non_negative, "metres >= 0"))
        return cls(**named, target=s.req("target", one_of(["closed", "open"])), value=0.0)

    def sensors(self):
        return [SensorRequest("framepos", self.left), SensorRequest("framepos", self.right)]

    def __call__(self, batch):
        xl, xr = (batch.get(r) for r in self.requests)
        width = norm(xl - xr)
        if self.target == "closed":
            return width
        if self.target == "open":
            return 1.0 - width
        return (width - self.value).abs()
