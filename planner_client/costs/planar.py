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

from planner_client.costs.helpers import norm
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
    """Obstacle bodies ``names`` as footprints for a round body ``a`` of ``radius`` m, and
    :meth:`distances` ``[S, T, n]`` from ``a``'s positions: fixed half-planes (``d = p · n − c``),
    fixed boxes (turned into their own frame by one matrix product), fixed disks, and the geoms
    of moving (mocap) bodies at their body's origin, placed at every step by the frame sensors
    :attr:`requests` name. Built by :func:`planar_obstacles`; tensors are float64 on the CPU,
    copied once to another device or dtype when a batch lives there."""

    a: str
    radius: float
    names: tuple[str, ...]
    plane_n: torch.Tensor  # [H, 2] inward normals
    plane_c: torch.Tensor  # [H] offsets: n · a point on the plane
    box_w: torch.Tensor  # [2, 2 Bf] p @ box_w: each fixed box's local x, y (rows of its axes)
    box_o: torch.Tensor  # [2 Bf] the centres in the same local coordinates
    box_half: torch.Tensor  # [Bf + Bm, 2] half sides, the fixed boxes first
    disk_c: torch.Tensor  # [Df, 2]
    disk_r: torch.Tensor  # [Df + Dm] radii, the fixed disks first
    moving: tuple[str, ...]  # mocap bodies, in the order of their position columns
    box_of: torch.Tensor  # [Bm] index into ``moving`` of each moving box
    box_turn: torch.Tensor  # [Bm] index into ``turning`` of each moving box
    disk_of: torch.Tensor  # [Dm] index into ``moving`` of each moving disk
    turning: tuple[str, ...]  # moving bodies with a box: their x axis read per step
    order: torch.Tensor  # [G] body index of each geom column (planes, boxes, disks)
    one_each: bool  # every body has one geom: ``order`` is a permutation
    _on: dict = field(default_factory=dict, repr=False)

    @property
    def requests(self) -> list[SensorRequest]:
        """``a``'s position, then each moving body's, then the x axis of each moving box's body."""
        return (
            [SensorRequest("framepos", self.a)]
            + [SensorRequest("framepos", n) for n in self.moving]
            + [SensorRequest("framexaxis", n) for n in self.turning]
        )

    def _tensors(self, like: torch.Tensor) -> dict[str, torch.Tensor]:
        key = (like.device, like.dtype)
        if key not in self._on:
            names = ("plane_n", "plane_c", "box_w", "box_o", "box_half", "disk_c", "disk_r")
            t = {n: getattr(self, n).to(like.device, like.dtype) for n in names}
            for n in ("box_of", "box_turn", "disk_of", "order"):
                t[n] = getattr(self, n).to(like.device)
            self._on[key] = t
        return self._on[key]

    def distances(
        self, p: torch.Tensor, pos: torch.Tensor | None, xaxis: torch.Tensor | None
    ) -> torch.Tensor:
        """Signed distances ``[S, T, n]`` from body ``a`` to each obstacle body, in
        :attr:`names`' order. ``p [S, T, 2]``: ``a``'s position; ``pos [S, T, Mm, 2]``: the
        moving bodies' positions, ``xaxis [S, T, Mt, 2]``: the x axes of the moving bodies with
        a box (None when there are none)."""
        c = self._tensors(p)
        parts = []
        if c["plane_n"].shape[0]:
            parts.append(p @ c["plane_n"].T - c["plane_c"])  # [S, T, H]
        local = []  # [S, T, B, 2] every box's centre-to-p in its own frame
        if c["box_o"].shape[0]:
            local.append((p @ c["box_w"] - c["box_o"]).unflatten(-1, (-1, 2)))
        if pos is not None and c["box_of"].shape[0]:
            d = p[..., None, :] - pos.index_select(-2, c["box_of"])  # [S, T, Bm, 2]
            axis = xaxis.index_select(-2, c["box_turn"])  # [S, T, Bm, 2]
            cos, sin = axis[..., 0], axis[..., 1]
            dx, dy = d[..., 0], d[..., 1]
            local.append(torch.stack((dx * cos + dy * sin, dy * cos - dx * sin), -1))
        if local:
            q = torch.cat(local, -2).abs_() - c["box_half"]  # [S, T, B, 2]
            out = q.clamp(min=0.0)
            inside = torch.maximum(q[..., 0], q[..., 1]).clamp_(max=0.0)
            parts.append(norm(out) + inside)
        disks = []  # [S, T, D, 2] every disk's centre-to-p
        if c["disk_c"].shape[0]:
            disks.append(p[..., None, :] - c["disk_c"])
        if pos is not None and c["disk_of"].shape[0]:
            disks.append(p[..., None, :] - pos.index_select(-2, c["disk_of"]))
        if disks:
            d = torch.cat(disks, -2)
            parts.append(norm(d) - c["disk_r"])
        geoms = torch.cat(parts, -1) - self.radius  # [S, T, G]
        if self.one_each:
            return geoms.index_select(-1, c["order"])
        out = geoms.new_full((*geoms.shape[:-1], len(self.names)), math.inf)
        return out.scatter_reduce_(-1, c["order"].expand_as(geoms), geoms, "amin")


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

    def t(x, shape, dtype=torch.float64):
        return torch.tensor(np.asarray(x, dtype=float).reshape(shape), dtype=dtype)

    n = [np.array([math.cos(p[2]), math.sin(p[2])]) for _, p, _ in planes]
    plane_c = [float(v @ p[:2]) for v, (_, p, _) in zip(n, planes)]
    # p @ box_w - box_o: each box's local x, y of p, the rows of R(-yaw) applied to p - centre
    w, o = [], []
    for _, p, _ in boxes:
        cos, sin = math.cos(p[2]), math.sin(p[2])
        w += [[cos, sin], [-sin, cos]]
        o += [cos * p[0] + sin * p[1], -sin * p[0] + cos * p[1]]
    turning = list(dict.fromkeys(moving[m] for _, m, _ in moving_boxes))
    order = (
        [i for i, _, _ in planes]
        + [i for i, _, _ in boxes]
        + [i for i, _, _ in moving_boxes]
        + [i for i, _, _ in disks]
        + [i for i, _, _ in moving_disks]
    )
    return PlanarObstacles(
        a=a,
        radius=radius,
        names=tuple(names),
        plane_n=t(n, (-1, 2)),
        plane_c=t(plane_c, (-1,)),
        box_w=t(np.array(w).T if w else [], (2, -1)),
        box_o=t(o, (-1,)),
        box_half=t([h for _, _, h in boxes] + [h for _, _, h in moving_boxes], (-1, 2)),
        disk_c=t([p[:2] for _, p, _ in disks], (-1, 2)),
        disk_r=t([h[0] for _, _, h in disks] + [h[0] for _, _, h in moving_disks], (-1,)),
        moving=tuple(moving),
        box_of=torch.tensor([m for _, m, _ in moving_boxes], dtype=torch.long),
        box_turn=torch.tensor(
            [turning.index(moving[m]) for _, m, _ in moving_boxes], dtype=torch.long
        ),
        disk_of=torch.tensor([m for _, m, _ in moving_disks], dtype=torch.long),
        turning=tuple(turning),
        order=torch.tensor(order, dtype=torch.long),
        one_each=sorted(order) == list(range(len(names))),
    )
