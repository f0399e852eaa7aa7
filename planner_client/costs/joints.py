"""Cost terms on the robot's joint positions: a redundant arm's limits and posture.

Neither is in the paper. A 7-joint arm reaching a 6-D pose has a null space that sampling
explores at random: over a long reactive episode (several grasps, each cube turned another way)
the posture drifts until a joint hits its limit and the hand can no longer turn the way the task
asks (the Panda's joint 7 at 2.9 rad, seen on re-grasps in ``pick_place_reactive``). Shapes:
S samples, T horizon steps; each term returns ``[S, T]`` from ``jointpos`` sensors ``[S, T, 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from planner_client.costs.base import CostTerm, TermContext, register
from planner_client.costs.helpers import constant, last_sum
from planner_client.sensors import SensorRequest
from shared.config import Section, positive, string_list, vector


def _joint_names(s: Section, ctx: TermContext, default: list[str], what: str) -> tuple[str, ...]:
    """The ``joints`` parameter, each name checked against the robot's joints."""
    names = s.opt("joints", tuple(default), string_list, "a list of joint names")
    for name in names:
        if name not in ctx.joints:
            raise s.error(
                "joints", "not a joint of the robot", name, f"one of: {', '.join(ctx.joints)}"
            )
    if not names:
        raise s.error(
            "joints",
            f"no joints to cost: the robot has no {what}",
            list(names),
            "at least one joint name",
        )
    return tuple(names)


def _positions(batch, requests) -> torch.Tensor:
    """``[S, T, n_joints]`` joint positions of the rollouts."""
    return batch.columns.take_all(batch.sensordata, requests)


@register("joint_limits")
@dataclass
class JointLimits(CostTerm):
    """Keep joints off their limits: Σ_j [relu(m − (q_j − lo_j)) + relu(m − (hi_j − q_j))] / m.

    0 while every joint is more than the margin ``m`` inside its range, 1 per joint at a limit,
    growing beyond it (MuJoCo's soft limits let a joint pass a little). ``joints`` defaults to
    every limited hinge of the robot.
    """

    joints: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    margin: float

    @classmethod
    def from_params(cls, s, ctx):
        limited = [n for n, j in ctx.joints.items() if j.range is not None and j.hinge]
        joints = _joint_names(s, ctx, limited, "limited hinge joints")
        for name in joints:
            if ctx.joints[name].range is None:
                raise s.error(
                    "joints",
                    "joint has no range in the model",
                    name,
                    f"a limited joint: {', '.join(limited)}",
                )
        margin = s.opt("margin", 0.2, positive, "radians (metres for a slide joint) > 0")
        return cls(
            joints=joints,
            lower=tuple(ctx.joints[n].range[0] for n in joints),
            upper=tuple(ctx.joints[n].range[1] for n in joints),
            margin=margin,
        )

    def sensors(self):
        return [SensorRequest("jointpos", n) for n in self.joints]

    def __call__(self, batch):
        q = _positions(batch, self.requests)  # [S, T, J]
        lo, hi = constant(self.lower, q.dtype, q.device), constant(self.upper, q.dtype, q.device)
        room = torch.minimum(q - lo, hi - q)  # [S, T, J]
        return last_sum(torch.clamp(self.margin - room, min=0.0)) / self.margin


@register("posture")
@dataclass
class Posture(CostTerm):
    """A nominal posture for the null space: Σ_j (q_j − q*_j)², q* the scenario's start pose
    (``robot.qpos``) unless ``target`` gives one value per joint. ``joints`` defaults to every
    hinge of the robot. With a small weight it decides only what the task leaves free."""

    joints: tuple[str, ...]
    target: tuple[float, ...]

    @classmethod
    def from_params(cls, s, ctx):
        hinges = [n for n, j in ctx.joints.items() if j.hinge]
        joints = _joint_names(s, ctx, hinges, "hinge joints")
        default = tuple(ctx.joints[n].start for n in joints)
        target = s.opt(
            "target", default, vector(len(joints)), f"{len(joints)} joint positions, one per joint"
        )
        return cls(joints=joints, target=target)

    def sensors(self):
        return [SensorRequest("jointpos", n) for n in self.joints]

    def __call__(self, batch):
        q = _positions(batch, self.requests)
        d = q - constant(self.target, q.dtype, q.device)
        return last_sum(d * d)
