"""Signed distances in the plane, in torch: a round body against upright obstacles at every
rollout step, from the body's position alone (the ``clearance`` term's ``planar`` method,
planner_client/costs/clearance.py).

MuJoCo's distance sensors (GEOMDIST) run a geom-pair distance query per obstacle and rollout
step, most of what a clearance costs an iteration. For a round robot among upright blocks and
walls the same numbers follow from 2-D geometry: the obstacles' footprints are read from the
model once (:class:`planner_client.guide.ObstacleGeoms`, the guide's shapes: a wall plane as a
half-plane, a box as a turned rectangle, a cylinder, sphere or capsule as a disk), and the
signed distance of the body's centre to each footprint (the maths of
:func:`planner_client.global_path.signed_distance`, batched) minus the body's radius is the
distance between the two, exactly as MuJoCo's while the two overlap in height (below).

Why it is exact. Call a geom's *core* the heights over which its horizontal section is its
whole footprint: a box's or cylinder's full height, a capsule's straight part, a sphere's
centre, a vertical plane's every height. Seen from above, every shape here projects onto its
footprint, so the 3-D distance is at least the 2-D one; at a height in both cores the two
footprints' nearest points belong to the shapes, so it is at most that. Hence equal whenever the
cores overlap in height, which :func:`planar_obstacles` checks at build time for every pair
(robot and blocks standing on the floor do). Inside an obstacle the planar value is the
horizontal depth, which is at least MuJoCo's (the shortest way out may be up).

What moves. The body ``a`` must keep its height and stay upright: its chain of joints has only
slides across the floor and hinges about the vertical. An obstacle is either fixed to the world
(no joint and no mocap in its chain: the walls), its footprint then a constant, or a mocap body
(the scenario's fixed objects, which the world can move: a disturbance, the ``move`` control op,
a randomised start, a scripted path), whose position (and, for a box, heading) is read at every
rollout step by a frame sensor, a copy of numbers MuJoCo has already computed. Heights are the
model's; an obstacle tipped over or lifted by a ``move`` is outside what this module models.
A jointed obstacle (a free box, an arm link) moves under its own dynamics and may tilt: none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from planner_client.guide import ObstacleGeoms
from planner_client.sensors import SensorRequest

# a direction counts as vertical (a cylinder's axis, a joint's) or horizontal (a wall's normal)
# within this of its unit vector's z
UPRIGHT_TOL = 1e-6
G = mujoco.mjtGeom
SPHERE, BOX, PLANE = G.mjGEOM_SPHERE, G.mjGEOM_BOX, G.mjGEOM_PLANE
ROUND = (SPHERE, G.mjGEOM_CYLINDER, G.mjGEOM_CAPSULE)


class NotPlanar(ValueError):
    """Why a body and its obstacles are not a planar problem (the message names the body or
    geom and what it has)."""


def _collision_geoms(model: mujoco.MjModel, body: int) -> list[int]:
    """``body``'s own geoms that collide (a drawn marker does not count, as for contacts)."""
    start, n = model.body_geomadr[body], model.body_geomnum[body]
    return [
        g for g in range(start, start + n) if model.geom_contype[g] or model.geom_conaffinity[g]
    ]


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    body = model.body(model.geom_bodyid[g]).name
    return model.geom(g).name or f"geom {g - model.body_geomadr[model.geom_bodyid[g]]} of {body}"


def _core(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> tuple[float, float]:
    """The heights ``(lo, hi)`` over which geom ``g``'s horizontal section is its footprint
    (module docstring), for an upright geom of a kind this module models."""
    t, size, z = int(model.geom_type[g]), model.geom_size[g], float(data.geom_xpos[g][2])
    if t == PLANE:
        return -math.inf, math.inf
    if t == SPHERE:
        return z, z
    half = float(size[2] if t == BOX else size[1])
    return z - half, z + half


def _upright(data: mujoco.MjData, g: int) -> bool:
    """Whether geom ``g``'s own z axis is vertical (a box's, cylinder's or capsule's)."""
    return abs(abs(float(data.geom_xmat[g][8])) - 1.0) < UPRIGHT_TOL


def _on_axis(data: mujoco.MjData, g: int, body: int) -> bool:
    """Whether geom ``g``'s centre is on the vertical line through ``body``'s origin (where
    the body's position sensor is): a turn about the vertical keeps it there."""
    return float(np.hypot(*(data.geom_xpos[g][:2] - data.xpos[body][:2]))) < 1e-9


def _chain(model: mujoco.MjModel, body: int) -> list[int]:
    """``body`` and its ancestors, world excluded."""
    out = []
    while body > 0:
        out.append(body)
        body = int(model.body_parentid[body])
    return out


def footprint_radius(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> float:
    """The radius of body ``body``'s collision geoms seen from above when each is a sphere,
    cylinder or capsule on the body's vertical axis through its origin (the point robots), and
    the body keeps its height and stays upright; else :class:`NotPlanar` says why. ``data``: a
    state with the kinematics done."""
    name = model.body(body).name
    geoms = _collision_geoms(model, body)
    if not geoms:
        raise NotPlanar(f"body {name!r} has no collision geom")
    for g in geoms:
        t, geom = int(model.geom_type[g]), _geom_name(model, g)
        if t not in ROUND:
            raise NotPlanar(f"{geom} of {name!r} is not a sphere, cylinder or capsule")
        if not _on_axis(data, g, body) or not (t == SPHERE or _upright(data, g)):
            raise NotPlanar(f"{geom} of {name!r} is not upright on the body's vertical axis")
    for b in _chain(model, body):
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
            t, z = int(model.jnt_type[j]), abs(float(data.xaxis[j][2]))
            across = t == mujoco.mjtJoint.mjJNT_SLIDE and z < UPRIGHT_TOL
            turn = t == mujoco.mjtJoint.mjJNT_HINGE and abs(z - 1.0) < UPRIGHT_TOL
            if not (across or turn):
                raise NotPlanar(
                    f"joint {model.joint(j).name!r} of {model.body(b).name!r} lifts or tilts "
                    f"{name!r} (only slides across the floor and hinges about the vertical keep "
                    "it planar)"
                )
    return max(float(model.geom_size[g][0]) for g in geoms)


@dataclass
class PlanarObstacles:
    """Obstacle bodies ``names`` as footprints for a round body ``a`` of ``radius`` m.

    Every footprint is a rounded rectangle, of half sides ``h`` about its centre c, turned by
    its yaw, grown by a rounding radius ρ: a box (h its half sides, ρ = 0), a disk (h = 0,
    ρ its radius), a wall's half-plane (a square of half side :data:`WALL_DEPTH` behind the
    plane, ρ = 0). The signed distance of a point p to it is that of
    :func:`planar_client.global_path.signed_distance` for a box, less ρ:

        q = |R(−yaw) (p − c)| − h,  d = ‖max(q, 0)‖ + min(max(q_x, q_y), 0) − ρ,

    and the distance between ``a`` and the footprint is d less ``a``'s radius, added to ρ. The
    local coordinates R(−yaw) (p − c) of all G footprints are one affine map of p, ``[2, 2G]``
    and ``[2G]``: constants for the geoms fixed to the world; a mocap body's geoms (at its
    origin) take theirs from its position and, a box, its x axis at each rollout step, read by
    the frame sensors :attr:`requests` names in the first sample: a mocap body moves alike in
    every sample (the world moves it, not the robot). Built by :func:`planar_obstacles`; tensors
    are float64 on the CPU, copied once to another device or dtype when a batch lives there."""

    a: str
    radius: float
    names: tuple[str, ...]
    fixed_w: torch.Tensor  # [2, 2F] the fixed geoms' R(−yaw) rows as columns
    fixed_o: torch.Tensor  # [2F] −R(−yaw) c
    half: torch.Tensor  # [G, 2] h, every geom's (fixed, then moving boxes, then moving disks)
    grow: torch.Tensor  # [G] ρ + ``a``'s radius
    moving: tuple[str, ...]  # mocap bodies, in the order of their position sensors
    turning: tuple[str, ...]  # the moving bodies with a box: their x axes are read too
    box_of: torch.Tensor  # [Bm] index into ``moving`` of each moving box
    box_turn: torch.Tensor  # [Bm] index into ``turning`` of each moving box
    disk_of: torch.Tensor  # [Dm] index into ``moving`` of each moving disk
    order: torch.Tensor  # [G] body index of each geom
    one_each: bool  # every body has one geom: ``order`` is a permutation of the bodies
    _on: dict = field(default_factory=dict, repr=False)

    @property
    def requests(self) -> list[SensorRequest]:
        """``a``'s position, each moving body's, and the x axis of each moving box's body."""
        return (
            [SensorRequest("framepos", self.a)]
            + [SensorRequest("framepos", n) for n in self.moving]
            + [SensorRequest("framexaxis", n) for n in self.turning]
        )

    def _tensors(self, like: torch.Tensor) -> dict:
        """The constants on ``like``'s device and dtype, and what :meth:`_affine` keeps."""
        key = (like.device, like.dtype)
        if key not in self._on:
            t = {n: getattr(self, n).to(like.device, like.dtype) for n in _FLOATS}
            t.update({n: getattr(self, n).to(like.device) for n in _INDICES})
            self._on[key] = t
        return self._on[key]

    def _affine(self, batch, c: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """The map's matrices ``[T, 2, 2G]`` and offsets ``[T, 1, 2G]``, one per rollout step:
        the fixed geoms' constants, and the moving ones' from their frames in the first sample,
        made again only when those changed (in most scenes the blocks stand still)."""
        steps = batch.sensordata.shape[1]
        if not self.moving:
            if c.get("steps") != steps:
                w, o = c["fixed_w"], c["fixed_o"]
                c["steps"], c["map"] = steps, (w.expand(steps, 2, -1), o.expand(steps, 1, -1))
            return c["map"]
        frames = batch.columns.take_all(batch.sensordata[0], self.requests[1:])  # [T, ·]
        seen = c.get("frames")
        if seen is not None and seen.shape == frames.shape and torch.equal(seen, frames):
            return c["map"]
        m = len(self.moving)
        pos = frames[:, : 3 * m].unflatten(-1, (m, 3))[..., :2]  # [T, Mm, 2]
        ws = [c["fixed_w"].expand(steps, 2, -1)]
        os = [c["fixed_o"].expand(steps, -1)]
        if self.turning:
            centre = pos.index_select(-2, c["box_of"])  # [T, Bm, 2]
            axes = frames[:, 3 * m :].unflatten(-1, (len(self.turning), 3))[..., :2]
            cos, sin = axes.index_select(-2, c["box_turn"]).unbind(-1)  # [T, Bm] each
            rot = torch.stack((cos, sin, -sin, cos), -1).unflatten(-1, (2, 2))  # R(−yaw)
            ws.append(rot.permute(0, 3, 1, 2).flatten(-2))  # [T, 2, 2 Bm]
            os.append(-(rot @ centre[..., None]).flatten(-3))  # [T, 2 Bm]
        if c["disk_of"].shape[0]:  # a disk's local frame need not turn: R = 1
            centre = pos.index_select(-2, c["disk_of"])  # [T, Dm, 2]
            eye = torch.eye(2, dtype=pos.dtype, device=pos.device)
            ws.append(eye.repeat(1, centre.shape[1]).expand(steps, 2, -1))
            os.append(-centre.flatten(-2))
        c["frames"] = frames.clone()  # sensordata's buffer is the next rollout's
        c["map"] = (torch.cat(ws, -1), torch.cat(os, -1)[:, None, :])
        return c["map"]

    def _excess(self, batch, c: dict) -> torch.Tensor:
        """``q = |R(−yaw) (p − c)| − h`` of every geom, ``[T, S, G, 2]`` (steps first: one
        matrix product per step)."""
        p = batch.get(self.requests[0])[..., :2].transpose(0, 1)  # [T, S, 2]
        w, o = self._affine(batch, c)
        return torch.baddbmm(o, p, w).unflatten(-1, (-1, 2)).abs_().sub_(c["half"])

    def distances(self, batch) -> torch.Tensor:
        """Signed distances ``[S, T, n]`` between ``a`` and each obstacle body, in
        :attr:`names`' order (a body's nearest geom)."""
        c = self._tensors(batch.sensordata)
        q = self._excess(batch, c)
        inside = torch.maximum(q[..., 0], q[..., 1]).clamp_(max=0.0)
        q = q.clamp_(min=0.0)
        geoms = torch.hypot(q[..., 0], q[..., 1]).add_(inside).sub_(c["grow"]).transpose(0, 1)
        if self.one_each:
            return torch.empty_like(geoms).index_copy_(-1, c["order"], geoms)
        out = geoms.new_full((*geoms.shape[:-1], len(self.names)), math.inf)
        return out.scatter_reduce_(-1, c["order"].expand_as(geoms), geoms, "amin")

    def shortfall(self, batch, margin: float) -> torch.Tensor:
        """``[T, S, G]`` (steps first) max(0, margin − d_g) of every geom g while ``a``'s
        centre is outside its footprint: the ``clearance`` term's, summed over geoms (the same
        as over bodies when each has one, :attr:`one_each`). With the centre inside (a
        penetration deeper than ``a``'s radius) it stays at margin + ρ + radius, the way
        MuJoCo's reading stops at −margin, and the few operations an iteration spends on it
        are spared (after a rollout each costs tens of µs on the CPU, docs/speed.md)."""
        c = self._tensors(batch.sensordata)
        reach = c.get(margin)  # [G] margin + ρ + radius, made once per margin
        if reach is None:
            reach = c[margin] = c["grow"] + margin
        q = self._excess(batch, c).clamp_(min=0.0)
        return (reach - torch.hypot(q[..., 0], q[..., 1])).clamp_(min=0.0)


_FLOATS = ("fixed_w", "fixed_o", "half", "grow")
_INDICES = ("box_of", "box_turn", "disk_of", "order")
# how far behind its plane a wall's square reaches, and along it: past any robot's workspace,
# and little enough that float32's rounding at this size (0.06 mm) stays far below a margin
WALL_DEPTH = 1000.0


def planar_obstacles(
    model: mujoco.MjModel, a: str, a_body: int, names: tuple[str, ...]
) -> PlanarObstacles:
    """The planar model of body ``a`` (id ``a_body``) against obstacle bodies ``names`` in
    ``model``, or :class:`NotPlanar` saying which body or geom keeps it from being one (module
    docstring): ``a`` not round or not kept upright at its height, an obstacle with a joint in
    its chain, a geom that is not an upright box, cylinder, capsule, sphere or vertical plane, a
    moving body's geom off its origin, or two geoms whose cores do not overlap in height."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    radius = footprint_radius(model, data, a_body)
    a_cores = [_core(model, data, g) for g in _collision_geoms(model, a_body)]
    planes, boxes, disks, moving_boxes, moving_disks = [], [], [], [], []
    moving: list[str] = []
    for i, name in enumerate(names):
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        chain = _chain(model, body)
        if any(model.body_jntnum[b] for b in chain):
            raise NotPlanar(f"obstacle {name!r} has a joint: it moves under its own dynamics")
        mocap = bool(model.body_mocapid[body] >= 0)
        if not mocap and any(model.body_mocapid[b] >= 0 for b in chain):
            raise NotPlanar(f"obstacle {name!r} rides on a mocap body")
        geoms = ObstacleGeoms.of(model, data, [body])
        wanted = _collision_geoms(model, body)
        if len(geoms.ids) != len(wanted):
            raise NotPlanar(f"obstacle {name!r} has a plane facing up (a floor)")
        poses = geoms.poses(data)
        for g, kind, half, pose in zip(geoms.ids, geoms.kinds, geoms.halves, poses):
            t, geom = int(model.geom_type[g]), _geom_name(model, g)
            if kind == "halfplane":
                if abs(float(data.geom_xmat[g][8])) > UPRIGHT_TOL:
                    raise NotPlanar(f"{geom} of {name!r} is a plane neither vertical nor level")
            elif t not in (BOX, *ROUND):
                raise NotPlanar(f"{geom} of {name!r} is not a box, cylinder, capsule or sphere")
            elif t != SPHERE and not _upright(data, g):
                raise NotPlanar(f"{geom} of {name!r} is not upright")
            lo, hi = _core(model, data, g)
            for a_lo, a_hi in a_cores:
                if a_hi < lo - 1e-9 or hi < a_lo - 1e-9:
                    raise NotPlanar(
                        f"{geom} of {name!r} spans heights {lo:.3f}-{hi:.3f} m and {a!r} "
                        f"{a_lo:.3f}-{a_hi:.3f} m: they do not overlap, and MuJoCo's distance "
                        "is not the planar one"
                    )
            if mocap:
                # placed by its body's position and, a box, its body's x axis
                turned = kind == "box" and not np.allclose(
                    data.geom_xmat[g][[0, 3]], data.xmat[body][[0, 3]], atol=1e-9
                )
                if not _on_axis(data, g, body) or turned:
                    raise NotPlanar(
                        f"{geom} of moving obstacle {name!r} is off its body's origin or axes"
                    )
                if name not in moving:
                    moving.append(name)
                m = moving.index(name)
                (moving_boxes if kind == "box" else moving_disks).append((i, m, half))
            else:
                {"halfplane": planes, "box": boxes, "disk": disks}[kind].append((i, pose, half))
    return _assemble(a, radius, names, planes, boxes, disks, moving, moving_boxes, moving_disks)


def _assemble(a, radius, names, planes, boxes, disks, moving, moving_boxes, moving_disks):
    """:class:`PlanarObstacles` from the geoms sorted by kind: fixed ``(body index, pose [3],
    half)`` and moving ``(body index, moving index, half)``."""
    fixed = []  # (R(−yaw) [2, 2], centre [2], h [2], ρ) of each fixed geom
    for _, (x, y, yaw), _ in planes:  # behind the plane: its normal is the square's local x
        n = np.array([math.cos(yaw), math.sin(yaw)])
        rot = np.array([n, [-n[1], n[0]]])
        fixed.append((rot, np.array([x, y]) - WALL_DEPTH * n, (WALL_DEPTH, WALL_DEPTH), 0.0))
    for _, (x, y, yaw), half in boxes:
        rot = np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]])
        fixed.append((rot, np.array([x, y]), half, 0.0))
    for _, (x, y, _), (r, _) in disks:
        fixed.append((np.eye(2), np.array([x, y]), (0.0, 0.0), r))
    w = np.concatenate([rot.T for rot, *_ in fixed], axis=1) if fixed else np.zeros((2, 0))
    o = np.concatenate([-(rot @ c) for rot, c, *_ in fixed]) if fixed else np.zeros(0)
    half = [h for _, _, h, _ in fixed] + [h for *_, h in moving_boxes]
    half += [(0.0, 0.0)] * len(moving_disks)
    grow = [rho for *_, rho in fixed] + [0.0] * len(moving_boxes)
    grow += [r for *_, (r, _) in moving_disks]
    turning = list(dict.fromkeys(moving[m] for _, m, _ in moving_boxes))
    order = [i for group in (planes, boxes, disks, moving_boxes, moving_disks) for i, *_ in group]

    def f64(x, *shape):
        return torch.tensor(np.asarray(x, dtype=float).reshape(shape), dtype=torch.float64)

    def index(x):
        return torch.tensor(x, dtype=torch.long)

    return PlanarObstacles(
        a=a,
        radius=radius,
        names=tuple(names),
        fixed_w=f64(w, 2, -1),
        fixed_o=f64(o, -1),
        half=f64(half, -1, 2),
        grow=f64(grow, -1) + radius,
        moving=tuple(moving),
        turning=tuple(turning),
        box_of=index([m for _, m, _ in moving_boxes]),
        box_turn=index([turning.index(moving[m]) for _, m, _ in moving_boxes]),
        disk_of=index([m for _, m, _ in moving_disks]),
        order=index(order),
        one_each=sorted(order) == list(range(len(names))),
    )
