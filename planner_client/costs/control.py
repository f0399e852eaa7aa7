"""Cost terms on the sampled controls themselves ``[S, T, nu]``. Every term returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass

from planner_client.costs.base import CostTerm, register
from planner_client.costs.helpers import last_sum
from shared.config import string_list


@register("control_effort")
@dataclass
class ControlEffort(CostTerm):
    """Σ_j u_j² over the control channels listed (all by default): a smoothness regulariser."""

    channels: tuple[int, ...] | None

    @classmethod
    def from_params(cls, s, ctx):
        names = s.opt("actuators", None, string_list, "a list of actuator names")
        if names is None:
            return cls(channels=None)
        return cls(channels=ctx.channels(s, "actuators", names))

    def sensors(self):
        return []

    def __call__(self, batch):
        u = batch.controls if self.channels is None else batch.controls[..., list(self.channels)]
        return last_sum(u * u)
