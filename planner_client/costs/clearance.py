"""A margin kept from obstacles by signed distance, for the robot or an object it moves (a base
that must not touch a block, a box pushed past a pillar). Returns ``[S, T]``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch

from planner_client.costs.base import register
from planner_client.costs.contact import Collision
from planner_client.costs.helpers import constant, last_sum
from planner_client.costs.planar import NotPlanar, PlanarObstacles, planar_obstacles
from shared.config import one_of, positive

METHODS = ("auto", "planar", "sensors")


@register("clearance")
@dataclass
class Clearance(Collision):
    """Σ_i (max(0, margin - d_i) / margin)²: 0 while body ``a`` is at least ``margin`` m from
    every obstacle i, 1 per obstacle at touching, growing quadratically with penetration.

    d_i is the signed distance between the geoms of ``a`` and of obstacle i in every rollout
    step: unlike ``contact_force`` (thesis Eq. 4.7), which only scores a touch, it keeps the
    declared margin, and a world that does not let a robot slide along a block (a bridge, a real
    base) is never touched. Unlike ``collision`` (linear) it is flat near the margin and steep
    near contact, so a path along an obstacle costs little and a touch a lot. ``a`` is a body
    (the robot, or a pushed or carried object); ``obstacles`` defaults to the walls and every
    ``obstacle`` object; ``margin`` is required (metres).

    ``method`` says how d_i is computed:

    - ``planar``: from ``a``'s position alone, in torch (:mod:`planner_client.costs.planar`):
      ``a``'s collision geoms are spheres, cylinders or capsules on its vertical axis and its
      joints keep it upright at its height (the point robots), and every obstacle is fixed to
      the world (the walls) or a mocap body (the scenario's fixed objects: their positions and
      headings are read by frame sensors, so a moved block is seen where it is), made of
      upright boxes, cylinders, capsules, spheres and vertical planes. d_i is then MuJoCo's to
      rounding wherever the two overlap in height, which is checked at build time (robot and
      blocks standing on the floor do; a shelf above the robot does not). Inside an obstacle
      the cost keeps growing until ``a``'s centre is inside its footprint. A drawn geom of
      ``a`` (no contacts) does not count, as for contacts.
    - ``sensors``: MuJoCo's GEOMDIST sensors, one per obstacle and rollout step, cut off at
      the margin (their reading stops at −margin inside): any shapes, any motion (a free box,
      an arm link), at a geom-pair distance query per obstacle and rollout step.
    - ``auto`` (default): ``planar`` where it applies, else ``sensors``. Declaring ``planar``
      where it does not apply is an error saying which body or geom keeps it from applying.
    """

    method: str = "sensors"  # how d_i is computed: planar or sensors (auto resolved at build)
    planar: PlanarObstacles | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_params(cls, s, ctx):
        s.req("margin", positive, "metres > 0")  # declared, never a default
        term = super().from_params(s, ctx)
        method = s.opt("method", "auto", one_of(METHODS))
        if method == "sensors" or not term.obstacles:
            return dataclasses.replace(term, method="sensors")
        model = ctx.resolve.model
        try:
            planar = planar_obstacles(model, term.a, ctx.resolve(term.a).id, term.obstacles)
        except NotPlanar as exc:
            if method == "planar":
                raise s.error(
                    "method", f"not a planar problem: {exc}", method, "auto or sensors"
                ) from None
            return dataclasses.replace(term, method="sensors")
        return dataclasses.replace(term, method="planar", planar=planar)

    def sensors(self):
        if self.planar is not None:
            return self.planar.requests
        return super().sensors()

    def distances(self, batch) -> torch.Tensor:
        """d_i ``[S, T, n_obstacles]``, in :attr:`obstacles`' order: the planar footprints'
        signed distances, or the sensors' cut off at the margin (both give the same cost)."""
        if self.planar is None:
            return batch.columns.take_all(batch.sensordata, self.requests)
        return self.planar.distances(batch)

    def __call__(self, batch):
        if not self.obstacles:
            return torch.zeros(
                batch.controls.shape[:2],
                dtype=batch.sensordata.dtype,
                device=batch.sensordata.device,
            )
        if self.planar is not None and self.planar.one_each:
            x = self.planar.shortfall(batch, self.margin)  # [T, S, G], G = n_obstacles
            scale = constant((self.margin**-2,) * x.shape[-1], x.dtype, x.device)
            return (x.mul_(x) @ scale).T  # Σ_i (x_i / margin)², as last_sum does
        x = torch.clamp(self.margin - self.distances(batch), min=0.0) / self.margin
        return last_sum(x * x)
