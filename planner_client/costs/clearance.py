"""A margin kept from obstacles by signed distance, for the robot or an object it moves (a base
that must not touch a block, a box pushed past a pillar). Returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from planner_client.costs.base import register
from planner_client.costs.contact import Collision
from planner_client.costs.helpers import last_sum
from shared.config import positive


@register("clearance")
@dataclass
class Clearance(Collision):
    """Σ_i (max(0, margin - d_i) / margin)²: 0 while body ``a`` is at least ``margin`` m from
    every obstacle i, 1 per obstacle at touching, growing quadratically with penetration.

    d_i is the signed distance between the geoms of ``a`` and of obstacle i (MuJoCo GEOMDIST
    sensors, cut off at the margin), in every rollout step: unlike ``contact_force`` (thesis
    Eq. 4.7), which only scores a touch, it keeps the declared margin, and a world that does not
    let a robot slide along a block (a bridge, a real base) is never touched. Unlike
    ``collision`` (linear) it is flat near the margin and steep near contact, so a path along an
    obstacle costs little and a touch a lot. ``a`` is a body (the robot, or a pushed or carried
    object); ``obstacles`` defaults to the walls and every ``obstacle`` object; ``margin`` is
    required (metres).
    """

    @classmethod
    def from_params(cls, s, ctx):
        s.req("margin", positive, "metres > 0")  # declared, never a default
        return super().from_params(s, ctx)

    def __call__(self, batch):
        if not self.obstacles:
            return torch.zeros(
                batch.controls.shape[:2],
                dtype=batch.sensordata.dtype,
                device=batch.sensordata.device,
            )
        d = batch.columns.take_all(batch.sensordata, self.requests)  # [S, T, n_obstacles]
        x = torch.clamp(self.margin - d, min=0.0) / self.margin
        return last_sum(x * x)
