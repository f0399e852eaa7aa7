"""The lab's cost terms for its two-link arm, a plugin module (docs/cost_terms.md, "Your own
cost terms"): a scenario beside this file names it with ``plugins: [lab_terms]``."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from planner_client.costs import CostTerm, register
from planner_client.sensors import SensorRequest
from shared.config import positive, string_list


@register("joint_speed")
@dataclass
class JointSpeed(CostTerm):
    """Σ_j relu(|q̇_j| − limit)²: how much faster than ``limit`` the named joints turn
    (rad/s for a hinge, m/s for a slide), 0 while they turn slower."""

    joints: tuple[str, ...]
    limit: float

    @classmethod
    def from_params(cls, s, ctx):
        # s.req: a key the YAML must give; s.opt: one with a default; each checks its value
        joints = s.req("joints", string_list, "a list of joint names")
        for name in joints:
            if name not in ctx.joints:  # the robot's hinge and slide joints
                raise s.error("joints", "not a joint of the robot", name, ", ".join(ctx.joints))
        return cls(joints=tuple(joints), limit=s.opt("limit", 0.5, positive, "a speed > 0"))

    def sensors(self):
        return [SensorRequest("jointvel", name) for name in self.joints]

    def __call__(self, batch):
        # batch.get: [S, T, 1] per joint; side by side [S, T, J]
        speed = torch.cat([batch.get(r) for r in self.requests], dim=-1).abs()
        return torch.relu(speed - self.limit).square().sum(-1)  # [S, T]


@register("command_change")
@dataclass
class CommandChange(CostTerm):
    """Σ_c (u_c(t) − u_c(t−1))² over the named actuators (all by default): a plan whose
    commands jump from step to step costs more. 0 at the first step."""

    channels: tuple[int, ...]

    @classmethod
    def from_params(cls, s, ctx):
        names = s.opt("actuators", tuple(ctx.actuators), string_list, "a list of actuators")
        # ctx.channels: each name checked, as its index in the last axis of batch.controls
        return cls(channels=ctx.channels(s, "actuators", names))

    def sensors(self):
        return []  # reads only the sampled controls

    def __call__(self, batch):
        u = batch.controls[..., list(self.channels)]  # [S, T, C] of [S, T, nu]
        change = torch.diff(u, dim=1).square().sum(-1)  # [S, T - 1]: one step short
        return torch.nn.functional.pad(change, (1, 0))  # [S, T]: 0 at t = 0
