"""Built-in cost terms. Each docstring cites the equation it implements; shapes are
``[S, T]`` per step unless stated (S samples, T horizon steps)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from shared.config import Section, one_of, positive, string_list, vector
from planner_client.costs.base import CostTerm, RolloutBatch, register
from planner_client.sensors import SensorRequest


# World axes a term may measure along: ``xy`` ignores height; ``xz`` and ``yz`` ignore one
# horizontal axis, e.g. a side grasp lining up level with the cube before it moves in along y.
_AXES = {"xy": [0, 1], "xz": [0, 2], "yz": [1, 2], "xyz": [0, 1, 2]}


def _axes(s: Section) -> str:
    return s.opt("axes", "xyz", one_of(list(_AXES)))


def _planar(x: torch.Tensor, axes: str) -> torch.Tensor:
    """The components of ``x [..., 3]`` along ``axes`` -> ``[..., 2 or 3]``."""
    return x if axes == "xyz" else x[..., _AXES[axes]]


@register("distance")
@dataclass
class Distance(CostTerm):
    """S_dist(a, b) = |x_a - (x_b + offset)| (paper Eq. 14, thesis Eq. 4.5); ``axes: xy`` ignores
    height. ``offset`` (world frame, metres; default 0) places a target relative to a movable
    object: the paper's pre-place and goal locations above cube B (Eqs. 25, 26, 29)."""
    a: str
    b: str
    axes: str
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), b=ctx.frame(s, "b"), axes=_axes(s),
                   offset=s.opt("offset", (0.0, 0.0, 0.0), vector(3), "[x, y, z] in metres"))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.b)]

    def __call__(self, batch: RolloutBatch) -> torch.Tensor:
        pa, pb = (batch.get(r) for r in self.requests)
        d = pa - pb
        if any(self.offset):
            d = d - torch.tensor(self.offset, dtype=d.dtype, device=d.device)
        return torch.linalg.vector_norm(_planar(d, self.axes), dim=-1)


@register("collision")
@dataclass
class Collision(CostTerm):
    """Keep-out cost for frame ``a`` against obstacles (the role of thesis Eq. 4.7).

    Eq. 4.7 sums contact forces with non-movable objects; here the signed geom distance d_i
    (MuJoCo GEOMDIST sensors) gives a smooth penalty that also acts before contact:
    Σ_i max(0, margin - d_i) / margin, which is 1 per obstacle at touching and grows with
    penetration. ``obstacles`` defaults to the arena walls and every object marked ``obstacle``
    in the scenario (by default every non-visual one, free objects included).
    """
    a: str
    obstacles: tuple[str, ...]
    margin: float

    @classmethod
    def from_params(cls, s, ctx):
        a = ctx.frame(s, "a")
        names = ctx.bodies(s, "obstacles", tuple(ctx.obstacles))
        return cls(a=a, obstacles=tuple(n for n in names if n != a),
                   margin=s.opt("margin", 0.1, positive, "metres > 0"))

    def sensors(self):
        return [SensorRequest("distance", self.a, o, cutoff=self.margin) for o in self.obstacles]

    def __call__(self, batch):
        if not self.obstacles:
            return torch.zeros(batch.controls.shape[:2], dtype=batch.sensordata.dtype)
        d = batch.layout.take_all(batch.sensordata, self.requests)        # [S, T, n_obstacles]
        return torch.clamp(self.margin - d, min=0.0).sum(-1) / self.margin


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
        return (u * u).sum(-1)


@register("velocity")
@dataclass
class Velocity(CostTerm):
    """|v_a|: linear speed of frame ``a`` (a velocity regulariser, e.g. to arrive at rest)."""
    a: str
    axes: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), axes=_axes(s))

    def sensors(self):
        return [SensorRequest("framelinvel", self.a)]

    def __call__(self, batch):
        return torch.linalg.vector_norm(_planar(batch.get(self.requests[0]), self.axes), dim=-1)
