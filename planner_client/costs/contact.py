"""Cost terms that keep a robot off obstacles: a distance margin, contact forces, and a moving
obstacle's predicted path (paper Eq. 22; thesis Eq. 4.7). Every term returns ``[S, T]``."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import torch

from planner_client.costs.base import CostTerm, Norm, register
from planner_client.costs.helpers import (
    SQUARE_FLOOR,
    axes_param,
    frame_params,
    last_sum,
    norm,
    sparse_norm,
)
from planner_client.sensors import SensorRequest
from shared.config import positive
from shared.geometry import select_axes


@register("collision")
@dataclass
class Collision(CostTerm):
    """Keep-out cost for frame ``a`` against obstacles (the role of thesis Eq. 4.7).

    thesis Eq. 4.7 sums contact forces with non-movable objects; here the signed geom distance d_i
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
        if ctx.resolve(a).kind == mujoco.mjtObj.mjOBJ_SITE:
            # MuJoCo's distance sensor measures a body's own geoms (not its children's); a site
            # has none, and the model would not compile
            raise s.error(
                "a",
                "distances need a body, not a site",
                a,
                "a body name, e.g. panda_hand (its own geoms, not the fingers)",
            )
        names = ctx.bodies(s, "obstacles", tuple(ctx.obstacles))
        return cls(
            a=a,
            obstacles=tuple(n for n in names if n != a),
            margin=s.opt("margin", 0.1, positive, "metres > 0"),
        )

    def sensors(self):
        return [SensorRequest("distance", self.a, o, cutoff=self.margin) for o in self.obstacles]

    def __call__(self, batch):
        if not self.obstacles:
            return torch.zeros(
                batch.controls.shape[:2],
                dtype=batch.sensordata.dtype,
                device=batch.sensordata.device,
            )
        d = batch.columns.take_all(batch.sensordata, self.requests)  # [S, T, n_obstacles]
        return last_sum(torch.clamp(self.margin - d, min=0.0)) / self.margin


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
    ``a`` must be a body (contact sensors do not take sites). An obstacle not touched adds
    1e-150 N rather than 0 (:func:`~planner_client.costs.helpers.sparse_norm`: most readings
    are zero, and the square root of zero is torch's slow case).
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
            return torch.zeros(
                batch.controls.shape[:2],
                dtype=batch.sensordata.dtype,
                device=batch.sensordata.device,
            )
        f = batch.columns.take_all(batch.sensordata, self.requests)  # [S, T, 3 n_obstacles]
        f = f.unflatten(-1, (len(self.requests), 3))  # [S, T, n_obstacles, 3]
        return last_sum(sparse_norm(f))

    def norms(self):
        return [
            Norm(tuple((0.0, ((req, i, 1.0),)) for i in range(3)), floor=SQUARE_FLOOR)
            for req in self.requests
        ]


@register("dynamic_obstacle")
@dataclass
class DynamicObstacle(CostTerm):
    """S_dyn_obs(R, D) = exp(-|x_R - x_D_pred|) (paper Eq. 22), per rollout step.

    x_D_pred(t) is the obstacle's position at rollout step t. The planner moves world-driven
    obstacles (fixed objects are mocap bodies that the world, or a person, moves) inside its
    rollouts at the velocity estimated from the last two states: the constant-velocity model of
    paper Eq. 22 (``planner_client/motion.py``). A jointed obstacle moves under its own dynamics in
    the rollout. Either way the prediction is the rollout's, so contact sensors and collision terms
    see the same predicted obstacle as this term.

    Parameters: ``a`` robot frame, ``obstacle`` frame, ``axes`` xyz (default) or xy. The value
    is 1 at contact of the two frame origins and decays per metre of separation.
    """

    a: str
    obstacle: str
    axes: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(**frame_params(s, ctx, "a", "obstacle"), axes=axes_param(s))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.obstacle)]

    def __call__(self, batch):
        x_r, x_d = (batch.get(r) for r in self.requests)
        return torch.exp(-norm(select_axes(x_r - x_d, self.axes)))
