"""Cost terms on frame poses: distances, speed, orientation, and how an end effector
approaches an object (paper Eqs. 14-15, 27; thesis Eqs. 4.5-4.6). Every term returns ``[S, T]``
(S samples, T horizon steps); positions are world-frame metres from ``framepos`` sensors."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from planner_client.costs.base import CostTerm, Norm, RolloutBatch, register
from planner_client.costs.helpers import (
    axes_param,
    constant,
    cosine,
    cosine_value,
    frame_params,
    norm,
)
from planner_client.sensors import SensorRequest
from shared.config import non_negative, one_of, positive, vector
from shared.geometry import AXES, select_axes


@register("distance")
@dataclass
class Distance(CostTerm):
    """S_dist(a, b) = |x_a - (x_b + offset)| (paper Eq. 14, thesis Eq. 4.5); ``axes: xy`` ignores
    height. ``offset`` (world frame, metres; default 0) places a target relative to a movable
    object: the paper's pre-place and goal locations above cube B (paper Eqs. 25, 26, 29)."""

    a: str
    b: str
    axes: str
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_params(cls, s, ctx):
        return cls(
            a=ctx.frame(s, "a"),
            b=ctx.frame(s, "b"),
            axes=axes_param(s),
            offset=s.opt("offset", (0.0, 0.0, 0.0), vector(3), "[x, y, z] in metres"),
        )

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.b)]

    def __call__(self, batch: RolloutBatch) -> torch.Tensor:
        pa, pb = (batch.get(r) for r in self.requests)
        d = pa - pb
        if any(self.offset):
            d = d - constant(self.offset, d.dtype, d.device)
        return norm(select_axes(d, self.axes))

    def norms(self):
        pa, pb = self.requests
        return [
            Norm(tuple((-self.offset[i], ((pa, i, 1.0), (pb, i, -1.0))) for i in AXES[self.axes]))
        ]


@register("velocity")
@dataclass
class Velocity(CostTerm):
    """|v_a|: linear speed of frame ``a`` (a velocity regulariser, e.g. to arrive at rest)."""

    a: str
    axes: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), axes=axes_param(s))

    def sensors(self):
        return [SensorRequest("framelinvel", self.a)]

    def __call__(self, batch):
        return norm(select_axes(batch.get(self.requests[0]), self.axes))

    def norms(self):
        return [Norm(tuple((0.0, ((self.requests[0], i, 1.0),)) for i in AXES[self.axes]))]


def symmetric_orientation_error_relative(axes: torch.Tensor) -> torch.Tensor:
    """:func:`shared.geometry.symmetric_orientation_error` from the axes of frame v expressed in
    frame u, ``[..., 9]``: v's x, y and z axis in u's coordinates one after the other, i.e. the
    columns of R_uᵀR_v, whose first two rows are the dot products u_a · v_i of paper Eq. 33.
    MuJoCo's ``framexaxis``, ``frameyaxis`` and ``framezaxis`` sensors of v with u as their
    reference frame give exactly this, in every rollout step, so the planner's cost is six tensor
    operations on the sensors instead of a product of two orientations (its quaternion form took
    some twenty operations: 235 µs on [200, 8] samples × steps, against 65 µs).
    """
    a = axes.abs()
    best = torch.maximum(torch.maximum(a[..., 0:2], a[..., 3:5]), a[..., 6:8])  # [..., 2]
    return (2.0 - best[..., 0] - best[..., 1]).clamp_min(0.0)


@register("orientation")
@dataclass
class Orientation(CostTerm):
    """S_ori(a, b) = φ(Σ_a, Σ_b) (paper Eq. 15, thesis Eq. 4.6), the weight being ω_ori.

    φ is the orientation metric for fully symmetric objects (paper Eq. 33): 0 whenever every axis
    of one frame is collinear with an axis of the other (any of a cube's 24 symmetries), at most
    2 - 2/√3. Read from the ``framexaxis``, ``frameyaxis`` and ``framezaxis`` sensors of ``b``
    in the frame of ``a`` ``[S, T, 9]``: the rotation from a to b, which MuJoCo computes in the
    rollout itself.
    """

    a: str
    b: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**frame_params(s, ctx, "a", "b"))

    def sensors(self):
        return [
            SensorRequest(kind, self.b, ref=self.a)
            for kind in ("framexaxis", "frameyaxis", "framezaxis")
        ]

    def __call__(self, batch):
        return symmetric_orientation_error_relative(
            batch.columns.take_all(batch.sensordata, self.requests)
        )


@register("reach")
@dataclass
class Reach(CostTerm):
    """S_reach(ee, O, θ) = |x_ee - x_O| + tilt_weight · |cos(z_ee, z_O) - θ| (paper Eq. 27).

    The term's weight is ω_reach and ``tilt_weight`` is ω_tilt / ω_reach. cos(z_ee, z_O) is the
    cosine between the z axes of the end effector ``ee`` and the object ``obj`` (``framezaxis``
    sensors). θ = -1 asks for the gripper perpendicular to the object's top face (z axes
    opposed), θ = 0 for the gripper parallel to the plane the object stands on.

    paper Eq. 27 writes the tilt residual without absolute value: linear in the cosine, so its
    minimum is always cos = -1 and θ only shifts the cost by a constant. The absolute residual
    used here is minimised exactly at cos = θ, as the text intends; for θ = -1 it equals the
    printed expression (cos >= -1 always). Absolute rather than squared, so the tilt cost keeps
    the same linear scale as the distance it is added to.

    ``obj_axis: up`` replaces z_O by the object's top-face normal: whichever of its axes ±x, ±y,
    ±z points most nearly up in the world (``framexaxis``/``frameyaxis``/``framezaxis``
    sensors). For a cube standing on its bottom face it is z_O itself; for one that fell on its
    side, z_O lies flat and Eq. 27 would ask for a hand pointing sideways at table height, so a
    dropped cube could never be grasped again from above.
    """

    ee: str
    obj: str
    theta: float
    tilt_weight: float
    obj_axis: str = "z"

    @classmethod
    def from_params(cls, s, ctx):
        return cls(
            **frame_params(s, ctx, "ee", "obj"),
            theta=s.req("theta", cosine_value, "a cosine in [-1, 1]"),
            tilt_weight=s.opt("tilt_weight", 1.0, non_negative, "a number >= 0"),
            obj_axis=s.opt("obj_axis", "z", one_of(("z", "up"))),
        )

    def sensors(self):
        axes = (
            ("framexaxis", "frameyaxis", "framezaxis") if self.obj_axis == "up" else ("framezaxis",)
        )
        return [
            SensorRequest("framepos", self.ee),
            SensorRequest("framepos", self.obj),
            SensorRequest("framezaxis", self.ee),
            *(SensorRequest(a, self.obj) for a in axes),
        ]

    def __call__(self, batch):
        x_ee, x_o, z_ee, *obj_axes = (batch.get(r) for r in self.requests)
        z_o = obj_axes[0] if self.obj_axis == "z" else top_axis(torch.stack(obj_axes, dim=-2))
        dist = norm(x_ee - x_o)
        return dist + self.tilt_weight * (cosine(z_ee, z_o) - self.theta).abs()


def top_axis(axes: torch.Tensor) -> torch.Tensor:
    """Of a body's axes ``[..., 3, 3]`` (x, y, z, each a world vector), the one, signed, that
    points most nearly up ``[..., 3]``: the normal of a box's top face however it lies."""
    up = axes[..., 2]  # [..., 3]
    best = up.abs().argmax(dim=-1, keepdim=True)  # [..., 1]
    axis = torch.take_along_dim(axes, best[..., None], dim=-2).squeeze(-2)
    return axis * torch.sign(torch.take_along_dim(up, best, dim=-1))


@register("tilt")
@dataclass
class Tilt(CostTerm):
    """|cos(z_ee, z_O) - θ|: the tilt summand of paper Eq. 27 on its own, as a constraint.

    Keeps the end effector's z axis at the angle θ to the object's while the distance is costed
    on something else, e.g. a grasped cube carried to its pre-place pose (paper Eq. 29): a hand that
    tilts there pinches the cube on its edges. Parameters and the absolute residual as in
    ``reach``; ``obj`` may be the held cube itself.
    """

    ee: str
    obj: str
    theta: float

    @classmethod
    def from_params(cls, s, ctx):
        return cls(
            **frame_params(s, ctx, "ee", "obj"),
            theta=s.req("theta", cosine_value, "a cosine in [-1, 1]"),
        )

    def sensors(self):
        return [SensorRequest("framezaxis", self.ee), SensorRequest("framezaxis", self.obj)]

    def __call__(self, batch):
        z_ee, z_o = (batch.get(r) for r in self.requests)
        return (cosine(z_ee, z_o) - self.theta).abs()


@register("approach_cone")
@dataclass
class ApproachCone(CostTerm):
    """relu(min(slope · relu(d_xy - radius), height) - (z_ee - z_O)): stay above a funnel over
    the object.

    d_xy is the horizontal distance of ``ee`` from ``obj``. Far away, the end effector must be at
    least ``height`` above the object's centre; closer than ``radius + height / slope`` the floor
    drops linearly, and within ``radius`` of the object's vertical axis it is the centre's height
    itself, so a top grasp arrives from above and never sweeps in at the object's level.

    Not in the paper. Without it, a reach that starts low (a cube taken from a hand carrying it
    3 cm over the table) swept in at table height and stopped beside the cube with a finger
    across its way, where rising costs more distance than a 12-step horizon gains. The flat
    bottom matters too: with a pointed cone, the sampled wobble of a hand 1 cm over the cube
    cost more the lower it went, and it hovered there.
    """

    ee: str
    obj: str
    slope: float
    height: float
    radius: float

    @classmethod
    def from_params(cls, s, ctx):
        return cls(
            **frame_params(s, ctx, "ee", "obj"),
            slope=s.opt("slope", 1.0, positive, "a number > 0"),
            height=s.opt("height", 0.05, positive, "metres > 0"),
            radius=s.opt("radius", 0.0, non_negative, "metres >= 0"),
        )

    def sensors(self):
        return [SensorRequest("framepos", self.ee), SensorRequest("framepos", self.obj)]

    def __call__(self, batch):
        x_ee, x_o = (batch.get(r) for r in self.requests)
        d_xy = norm(x_ee[..., :2] - x_o[..., :2])
        floor = torch.clamp(self.slope * torch.relu(d_xy - self.radius), max=self.height)
        return torch.relu(floor - (x_ee[..., 2] - x_o[..., 2]))
