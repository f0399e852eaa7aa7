"""Cost terms of the push/pull and pick/place objectives (paper Sec. III.A, thesis Sec. 4.2.1).

Each docstring cites the equation it implements. Shapes: S samples, T horizon steps; every term
returns ``[S, T]``. Positions are world-frame metres from ``framepos`` sensors.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import torch

from shared.config import Section, non_negative, number, one_of, positive, string_list
from shared.geometry import symmetric_orientation_error_quat
from planner_client.costs.base import CostTerm, RolloutBatch, TermContext, register
from planner_client.costs.terms import _axes, _planar
from planner_client.sensors import SensorRequest

# Floor of |a|·|b| in a cosine: a robot exactly on the object, an object exactly on the goal or a
# zero control has no direction, and must cost nothing rather than NaN.
_TINY = 1e-12


def _cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """cos of the angle between ``a`` and ``b`` ``[..., d]`` -> ``[...]``; 0 if either is 0.

    Near zero, |a·b| <= |a||b| keeps the ratio in [-1, 1], so the cost stays bounded and
    continuous there too.
    """
    den = torch.linalg.vector_norm(a, dim=-1) * torch.linalg.vector_norm(b, dim=-1)
    return (a * b).sum(-1) / den.clamp_min(_TINY)


def _planar_axes(s: Section) -> str:
    # Robot, object and goal centres sit at different heights; the planar angle is the one
    # that says whether the robot is behind the object.
    return s.opt("axes", "xy", one_of(["xy", "xyz"]))


def _cos_rog(batch: RolloutBatch, a: str, obj: str, goal: str, axes: str) -> torch.Tensor:
    """cos θ_ROG of paper Eq. 16: angle at the object O between robot R and goal G, ``[S, T]``."""
    x_r, x_o, x_g = (batch.get(SensorRequest("framepos", f)) for f in (a, obj, goal))
    return _cosine(_planar(x_r - x_o, axes), _planar(x_g - x_o, axes))


def _frames(s: Section, ctx: TermContext, *keys: str) -> dict[str, str]:
    return {k: ctx.frame(s, k) for k in keys}


@register("orientation")
@dataclass
class Orientation(CostTerm):
    """S_ori(a, b) = φ(Σ_a, Σ_b) (paper Eq. 15, thesis Eq. 4.6), the weight being ω_ori.

    φ is the orientation metric for fully symmetric objects (paper Eq. 33): 0 whenever every axis
    of one frame is collinear with an axis of the other (any of a cube's 24 symmetries), at most
    2 - 2/√3. Read from the ``framequat`` sensors of both frames ``[S, T, 4]``.
    """
    a: str
    b: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**_frames(s, ctx, "a", "b"))

    def sensors(self):
        return [SensorRequest("framequat", self.a), SensorRequest("framequat", self.b)]

    def __call__(self, batch):
        qa, qb = (batch.get(r) for r in self.requests)
        return symmetric_orientation_error_quat(qa, qb)


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
        return cls(**_frames(s, ctx, "a", "obj", "goal"), axes=_planar_axes(s))

    def sensors(self):
        return [SensorRequest("framepos", f) for f in (self.a, self.obj, self.goal)]

    def __call__(self, batch):
        return torch.relu(_cos_rog(batch, self.a, self.obj, self.goal, self.axes))


@register("pull_align")
@dataclass
class PullAlign(PushAlign):
    """S_align_pull(R, O, G) = f(-cos θ_ROG), f = relu (paper Eq. 20).

    The mirror of ``push_align``: 0 while the robot R is on the goal's side of the object O
    (where pulling O brings it to G), rising to 1 with R directly behind O. Same parameters.
    """

    def __call__(self, batch):
        return torch.relu(-_cos_rog(batch, self.a, self.obj, self.goal, self.axes))


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
    robot close to the object (Eq. 13); a scenario that pulls without that precondition must
    still let the robot drive up to the object, which Eq. 21 alone forbids.
    """
    a: str
    obj: str
    channels: tuple[int, ...]
    axes: str
    within: float | None = None

    @classmethod
    def from_params(cls, s, ctx):
        frames = _frames(s, ctx, "a", "obj")
        axes = _planar_axes(s)
        names = s.req("actuators", string_list, "a list of actuator names")
        if len(names) != len(axes):
            raise s.error("actuators", f"needs one velocity actuator per axis of {axes!r}",
                          list(names), f"{len(axes)} actuator names")
        return cls(**frames, channels=ctx.channels(s, "actuators", names), axes=axes,
                   within=s.opt("within", None, positive, "metres > 0"))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.obj)]

    def __call__(self, batch):
        x_r, x_o = (batch.get(r) for r in self.requests)
        u = batch.controls[..., list(self.channels)]
        d = _planar(x_o - x_r, self.axes)
        cost = torch.relu(_cosine(d, u))
        if self.within is not None:
            cost = cost * (torch.linalg.vector_norm(d, dim=-1) <= self.within)
        return cost


@register("dynamic_obstacle")
@dataclass
class DynamicObstacle(CostTerm):
    """S_dyn_obs(R, D) = exp(-|x_R - x_D_pred|) (paper Eq. 22), per rollout step.

    x_D_pred(t) is the obstacle's position at rollout step t. The planner moves world-driven
    obstacles (fixed objects are mocap bodies that the world, or a person, moves) inside its
    rollouts at the velocity estimated from the last two states: the constant-velocity model of
    Eq. 22 (``planner_client/motion.py``). A jointed obstacle moves under its own dynamics in the
    rollout. Either way the prediction is the rollout's, so contact sensors and collision terms
    see the same predicted obstacle as this term.

    Parameters: ``a`` robot frame, ``obstacle`` frame, ``axes`` xyz (default) or xy. The value
    is 1 at contact of the two frame origins and decays per metre of separation.
    """
    a: str
    obstacle: str
    axes: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**_frames(s, ctx, "a", "obstacle"), axes=_axes(s))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.obstacle)]

    def __call__(self, batch):
        x_r, x_d = (batch.get(r) for r in self.requests)
        return torch.exp(-torch.linalg.vector_norm(_planar(x_r - x_d, self.axes), dim=-1))


def _cosine_value(value) -> float:
    v = number(value)
    if not -1.0 <= v <= 1.0:
        raise ValueError("must be in [-1, 1]")
    return v


@register("reach")
@dataclass
class Reach(CostTerm):
    """S_reach(ee, O, θ) = |x_ee - x_O| + tilt_weight · |cos(z_ee, z_O) - θ| (paper Eq. 27).

    The term's weight is ω_reach and ``tilt_weight`` is ω_tilt / ω_reach. cos(z_ee, z_O) is the
    cosine between the z axes of the end effector ``ee`` and the object ``obj`` (``framezaxis``
    sensors). θ = -1 asks for the gripper perpendicular to the object's top face (z axes
    opposed), θ = 0 for the gripper parallel to the plane the object stands on.

    Eq. 27 writes the tilt residual without absolute value: linear in the cosine, so its
    minimum is always cos = -1 and θ only shifts the cost by a constant. The absolute residual
    used here is minimised exactly at cos = θ, as the text intends; for θ = -1 it equals the
    printed expression (cos >= -1 always). Absolute rather than squared, so the tilt cost keeps
    the same linear scale as the distance it is added to.
    """
    ee: str
    obj: str
    theta: float
    tilt_weight: float

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**_frames(s, ctx, "ee", "obj"),
                   theta=s.req("theta", _cosine_value, "a cosine in [-1, 1]"),
                   tilt_weight=s.opt("tilt_weight", 1.0, non_negative, "a number >= 0"))

    def sensors(self):
        return [SensorRequest("framepos", self.ee), SensorRequest("framepos", self.obj),
                SensorRequest("framezaxis", self.ee), SensorRequest("framezaxis", self.obj)]

    def __call__(self, batch):
        x_ee, x_o, z_ee, z_o = (batch.get(r) for r in self.requests)
        dist = torch.linalg.vector_norm(x_ee - x_o, dim=-1)
        return dist + self.tilt_weight * (_cosine(z_ee, z_o) - self.theta).abs()


@register("tilt")
@dataclass
class Tilt(CostTerm):
    """|cos(z_ee, z_O) - θ|: the tilt summand of paper Eq. 27 on its own, as a constraint.

    Keeps the end effector's z axis at the angle θ to the object's while the distance is costed
    on something else, e.g. a grasped cube carried to its pre-place pose (Eq. 29): a hand that
    tilts there pinches the cube on its edges. Parameters and the absolute residual as in
    ``reach``; ``obj`` may be the held cube itself.
    """
    ee: str
    obj: str
    theta: float

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**_frames(s, ctx, "ee", "obj"),
                   theta=s.req("theta", _cosine_value, "a cosine in [-1, 1]"))

    def sensors(self):
        return [SensorRequest("framezaxis", self.ee), SensorRequest("framezaxis", self.obj)]

    def __call__(self, batch):
        z_ee, z_o = (batch.get(r) for r in self.requests)
        return (_cosine(z_ee, z_o) - self.theta).abs()


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
        return cls(**_frames(s, ctx, "ee", "obj"),
                   slope=s.opt("slope", 1.0, positive, "a number > 0"),
                   height=s.opt("height", 0.05, positive, "metres > 0"),
                   radius=s.opt("radius", 0.0, non_negative, "metres >= 0"))

    def sensors(self):
        return [SensorRequest("framepos", self.ee), SensorRequest("framepos", self.obj)]

    def __call__(self, batch):
        x_ee, x_o = (batch.get(r) for r in self.requests)
        d_xy = torch.linalg.vector_norm(x_ee[..., :2] - x_o[..., :2], dim=-1)
        floor = torch.clamp(self.slope * torch.relu(d_xy - self.radius), max=self.height)
        return torch.relu(floor - (x_ee[..., 2] - x_o[..., 2]))


@register("gripper_width")
@dataclass
class GripperWidth(CostTerm):
    """Gripper opening l = |x_left - x_right| between two frames, e.g. fingertip sites.

    ``target: closed`` gives l (paper Eq. 28, closing to grasp), ``target: open`` gives 1 - l
    (Eq. 30, opening to release; l in metres stays far below 1), ``value: w`` gives |l - w|
    (e.g. the cube's width, to hold without squeezing). Exactly one of ``target``/``value``.
    """
    left: str
    right: str
    target: str
    value: float

    @classmethod
    def from_params(cls, s, ctx):
        frames = _frames(s, ctx, "left", "right")
        if s.has("target") == s.has("value"):
            raise s.error("target", "give exactly one of target (closed|open) or value (metres)",
                          expected="target: closed, target: open or value: <width>")
        if s.has("value"):
            return cls(**frames, target="value", value=s.req("value", non_negative, "metres >= 0"))
        return cls(**frames, target=s.req("target", one_of(["closed", "open"])), value=0.0)

    def sensors(self):
        return [SensorRequest("framepos", self.left), SensorRequest("framepos", self.right)]

    def __call__(self, batch):
        xl, xr = (batch.get(r) for r in self.requests)
        width = torch.linalg.vector_norm(xl - xr, dim=-1)
        if self.target == "closed":
            return width
        if self.target == "open":
            return 1.0 - width
        return (width - self.value).abs()


@register("contact_force")
@dataclass
class ContactForce(CostTerm):
    """S_coll(a) = Σ_i |F_contact(a, i)| over non-movable objects i (thesis Eq. 4.7), newtons.

    F_contact(a, i) is the net contact force between body ``a`` with its subtree (all links of
    a robot) and the geoms of body i, one MuJoCo CONTACT sensor per obstacle, reduced to a net
    force [3] inside MuJoCo (it only scans the step's contact list: cheaper than the distance
    sensors of ``collision``). Unlike
    ``collision`` it is 0 until touching and carries no gradient of distance: it scores how hard
    a sample hits. ``obstacles`` defaults as for ``collision`` (walls and ``obstacle`` objects);
    ``a`` must be a body (contact sensors do not take sites).
    """
    a: str
    obstacles: tuple[str, ...]

    @classmethod
    def from_params(cls, s, ctx):
        a = ctx.frame(s, "a")
        if ctx.resolve(a).kind == mujoco.mjtObj.mjOBJ_SITE:
            raise s.error("a", "contact forces need a body, not a site", a, "a body name or robot")
        names = ctx.bodies(s, "obstacles", tuple(ctx.obstacles))
        for name in names:
            if ctx.resolve(name).kind == mujoco.mjtObj.mjOBJ_SITE:
                raise s.error("obstacles", "contact forces need bodies, not sites", name)
        return cls(a=a, obstacles=tuple(n for n in names if n != a))

    def sensors(self):
        return [SensorRequest("contactforce", self.a, o) for o in self.obstacles]

    def __call__(self, batch):
        if not self.obstacles:
            return torch.zeros(batch.controls.shape[:2], dtype=batch.sensordata.dtype)
        f = batch.layout.take_all(batch.sensordata, self.requests)         # [S, T, 3 n_obstacles]
        f = f.unflatten(-1, (len(self.requests), 3))                       # [S, T, n_obstacles, 3]
        return torch.linalg.vector_norm(f, dim=-1).sum(-1)
