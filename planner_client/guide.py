"""The global guide (the scenario's ``guide:`` key): a path over the whole scene for the robot or
for an object it moves, kept up to date beside the planner, and the sub-goal along it.

The local planner looks 0.75 s ahead and is pulled into local minima by its distance costs (a
U-shaped obstacle, a box in a corner); thesis Sec. 5.2 names a global planner as the remedy.
:class:`GuideState` is what the planner's model and its cost terms share: the current path (as
tensors for :mod:`planner_client.costs.path`) and the site ``site:guide``, the sub-goal
``lookahead`` metres along the path beyond the guided body, which any term can name as a frame.
:class:`Guide` plans in a thread of its own from snapshots of the mirrored scene: at start, and
again when an obstacle moves (a disturbance, the ``move`` control op), the goal moves, or the
guided body leaves the path. In real time an iteration never waits for it: a new path is used
from the first iteration after it is ready. In lock-step the path requested at one iteration is
used from the next, waiting for it if need be, so an episode stays the same for its seed; the
first path is computed before the first iteration plans.

Given the planner's map (a field source, :class:`~planner_client.costs.base.FieldSource`), the
guide plans on it too: cells closer than the body's radius plus ``inflate`` to an obstacle of
its newest 2-D signed distance field are blocked as the declared obstacles' are, and a new field
that the current path passes through (closer than the body's radius) is planned on again.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch

from planner_client import global_path
from planner_client.global_path import MapObstacles, PathResult, Room, Shape
from shared.frames import FrameResolver
from shared.scenario import Scenario
from shared.scenario.guide import GuideConfig
from shared.scene import WALL_NAMES

if TYPE_CHECKING:  # the cost terms import the guide: a type only
    from planner_client.costs.base import FieldSource

log = logging.getLogger(__name__)

SITE = "guide"  # the sub-goal's site in the planner's model; YAML frame ``site:guide``
SITE_BODY = "guide_subgoal"  # the body that carries it

# a guide's planner: (shapes, start, goal, resolution, radius, room, field) -> a path
METHODS: dict[str, Callable[..., PathResult]] = {"astar": global_path.plan}


def add_site(spec: mujoco.MjSpec) -> None:
    """The sub-goal's site, on a body of its own fixed to the world (no joint, no geom: nothing
    to simulate) that :class:`Guide` moves between iterations through ``model.body_pos``
    (MuJoCo places sites of the world body once, not at every step)."""
    body = spec.worldbody.add_body(name=SITE_BODY, pos=[0.0, 0.0, 0.0])
    body.add_site(name=SITE, pos=[0.0, 0.0, 0.0], size=[0.05, 0.0, 0.0], group=5)


@dataclass(frozen=True)
class PathTensors:
    """The path as the terms read it: segment starts ``a [M, 2]``, their vectors ``ab [M, 2]``
    and squared lengths ``ab2 [M]``, the arc length at each start ``s0 [M]`` and the path's
    ``length``; or, without a path, the ``goal [2]`` alone (``a`` empty). A guide with room
    for the robot also has the cells on the way ``dense [K, 2]`` and the robot's place beside
    the object at each, ``handles [K, 2]`` (0 where there is none); else both are empty."""

    a: torch.Tensor
    ab: torch.Tensor
    ab2: torch.Tensor
    s0: torch.Tensor
    length: float
    goal: torch.Tensor
    dense: torch.Tensor
    handles: torch.Tensor
    dense_s: torch.Tensor  # [K] arc length along the path at each dense cell

    @classmethod
    def of(cls, result: PathResult | None, goal: np.ndarray) -> PathTensors:
        points = None if result is None else result.points
        pts = np.zeros((0, 2)) if points is None else points
        dense = np.zeros((0, 2))
        hands = np.zeros((0, 2))
        if result is not None and result.dense is not None:
            dense, hands = result.dense, np.nan_to_num(result.handles)
        dsteps = np.linalg.norm(np.diff(dense, axis=0), axis=1)
        a, b = pts[:-1], pts[1:]
        seg = np.linalg.norm(b - a, axis=1)
        t = _tensor
        return cls(
            a=t(a),
            ab=t(b - a),
            ab2=t(np.maximum(seg**2, 1e-18)),
            s0=t(np.concatenate([[0.0], np.cumsum(seg)[:-1]]) if len(seg) else seg),
            length=float(seg.sum()),
            goal=t(np.asarray(goal, float)[:2]),
            dense=t(dense),
            handles=t(hands),
            dense_s=t(np.concatenate([[0.0], np.cumsum(dsteps)])[: len(dense)]),
        )


def _tensor(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float64)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Σ over the last axis (x, y) of a · b, as a matrix product (torch's reduction over a
    last axis of two is the slow way: planner_client.costs.helpers.last_sum)."""
    return (a * b) @ _ONES2


_ONES2 = torch.ones(2, dtype=torch.float64)


def project(p: torch.Tensor, path: PathTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """Distance of points ``p [..., 2]`` to the path and the path length left beyond their
    nearest point on it, both ``[...]``; without a path, 0 and the straight distance to the
    goal."""
    if path.a.shape[0] == 0:
        d = p - path.goal
        return torch.zeros(p.shape[:-1], dtype=p.dtype), _dot(d, d).sqrt_()
    d = p[..., None, :] - path.a  # [..., M, 2]
    t = (_dot(d, path.ab) / path.ab2).clamp_(0.0, 1.0)  # [..., M]
    off = d - t[..., None] * path.ab
    dist2 = _dot(off, off)
    best = dist2.argmin(-1, keepdim=True)
    dist = dist2.gather(-1, best).squeeze(-1).sqrt_()
    s = (path.s0 + t * path.ab2.sqrt()).gather(-1, best).squeeze(-1)
    return dist, path.length - s


def handle_target(p: torch.Tensor, path: PathTensors) -> torch.Tensor:
    """Where the robot should stand ``[..., 2]`` beside an object at ``p [..., 2]``: the handle
    of the path cell at the object's nearest point on the path; ``p`` itself without one."""
    if path.dense.shape[0] == 0:
        return p
    s = path.length - project(p, path)[1]
    i = torch.searchsorted(path.dense_s, s).clamp_(max=path.dense.shape[0] - 1)
    return p + path.handles[i]


def project_point(p: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """Distance of one point ``p [2]`` from the polyline ``points [N, 2]`` and the arc length
    at its nearest point on it (numpy: one point costs torch more than the maths)."""
    a, ab = points[:-1], np.diff(points, axis=0)
    ab2 = np.maximum((ab * ab).sum(1), 1e-18)
    t = np.clip(((p - a) * ab).sum(1) / ab2, 0.0, 1.0)
    off = p - (a + t[:, None] * ab)
    dist = np.hypot(off[:, 0], off[:, 1])
    i = int(np.argmin(dist))
    seg = np.sqrt(ab2)
    return float(dist[i]), float(seg[:i].sum() + t[i] * seg[i])


def resample(points: np.ndarray, step: float) -> np.ndarray:
    """Points ``[K, 2]`` along the polyline ``points [N, 2]``, at most ``step`` apart, its ends
    included."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], int(s[-1] / step) + 2)
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], axis=1)


def point_at(points: np.ndarray, s: float) -> np.ndarray:
    """The point ``s`` metres along the polyline ``points [N, 2]`` (clamped to its ends)."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    for a, b, length in zip(points[:-1], points[1:], seg):
        if s <= length and length > 0:
            return a + (b - a) * (s / length)
        s -= length
    return points[-1]


class GuideState:
    """The guide's part of the planner's model, shared with its terms: config, the frames, the
    current path (:attr:`path`, replaced whole, never modified) and whether it exists."""

    def __init__(self, cfg: GuideConfig, scenario: Scenario):
        self.cfg = cfg
        self.scenario = scenario
        self.path = PathTensors.of(None, np.zeros(2))
        self.points: np.ndarray | None = None  # [N, 2] the current path's corners
        self.exists = False
        self.version = 0  # paths planned so far

    def __repr__(self) -> str:  # a term's key: one guide per planner
        return f"GuideState({self.cfg.for_!r} -> {self.cfg.goal!r})"


@dataclass(frozen=True)
class Snapshot:
    """The scene as a guide plans on it: the obstacle geoms' poses ``[G, 3]`` (x, y, yaw), the
    guided body and the goal (x, y), and the map's newest field (None: no map)."""

    poses: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    field: MapObstacles | None = None

    def moved(self, other: Snapshot, reach: np.ndarray, tol: float) -> bool:
        """Whether an obstacle (a point ``reach [G]`` m from its centre, turning with it) or the
        goal moved by more than ``tol`` m between the two."""
        shift = np.hypot(*(self.poses[:, :2] - other.poses[:, :2]).T)
        turn = np.abs(np.remainder(self.poses[:, 2] - other.poses[:, 2] + np.pi, 2 * np.pi) - np.pi)
        if np.any(shift + turn * reach > tol):
            return True
        return float(np.linalg.norm(self.goal - other.goal)) > tol


def footprint(model: mujoco.MjModel, body: int, inscribed: bool) -> float:
    """Radius of a body's own collision geoms seen from above, about its origin: a box by its
    smaller half-side (``inscribed``: an object pushed squarely along a wall) or its half
    diagonal, a cylinder or sphere by its radius."""
    r = 0.0
    for g in range(model.body_geomadr[body], model.body_geomadr[body] + model.body_geomnum[body]):
        if not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        size, t = model.geom_size[g], int(model.geom_type[g])
        if t == mujoco.mjtGeom.mjGEOM_BOX:
            half = min(size[0], size[1]) if inscribed else math.hypot(size[0], size[1])
        elif t == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        elif t in (mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_SDF):
            half = float(model.geom_rbound[g])
        else:
            half = float(size[0])
        r = max(r, float(np.linalg.norm(model.geom_pos[g][:2])) + half)
    return r


@dataclass(frozen=True)
class ObstacleGeoms:
    """The collision geoms of the obstacle bodies as the guide sees them from above: a wall
    plane as a half-plane, a box as a turned rectangle, any other geom as a disk of its radius
    (a mesh: of its bounding sphere); planes facing up (floors) are left out. Their kinds and
    sizes are the model's; their poses are read from each state (:meth:`poses`)."""

    ids: np.ndarray  # [G] geom ids
    kinds: tuple[str, ...]
    halves: tuple[tuple[float, float], ...]

    @classmethod
    def of(cls, model: mujoco.MjModel, data: mujoco.MjData, bodies: list[int]) -> ObstacleGeoms:
        """``data``: a state with the kinematics done (a plane's facing is read from it)."""
        ids, kinds, halves = [], [], []
        for body in bodies:
            start, n = model.body_geomadr[body], model.body_geomnum[body]
            for g in range(start, start + n):
                if not (model.geom_contype[g] or model.geom_conaffinity[g]):
                    continue
                t, size = int(model.geom_type[g]), model.geom_size[g]
                if t == mujoco.mjtGeom.mjGEOM_PLANE:
                    if abs(data.geom_xmat[g][8]) > 0.7:  # the plane's normal points up
                        continue
                    kind, half = "halfplane", (0.0, 0.0)
                elif t == mujoco.mjtGeom.mjGEOM_BOX:
                    kind, half = "box", (float(size[0]), float(size[1]))
                elif t == mujoco.mjtGeom.mjGEOM_MESH:
                    kind, half = "disk", (float(model.geom_rbound[g]), 0.0)
                else:
                    kind, half = "disk", (float(size[0]), 0.0)
                ids.append(g)
                kinds.append(kind)
                halves.append(half)
        return cls(np.array(ids, dtype=int), tuple(kinds), tuple(halves))

    @property
    def reach(self) -> np.ndarray:
        """``[G]`` how far each shape reaches from its centre (0 for a half-plane)."""
        return np.array([math.hypot(*h) for h in self.halves])

    def poses(self, data: mujoco.MjData) -> np.ndarray:
        """``[G, 3]`` each geom's x, y and heading: a box's yaw, a plane's normal's."""
        xmat = data.geom_xmat[self.ids]
        yaw = np.where(
            [k == "halfplane" for k in self.kinds],
            np.arctan2(xmat[:, 5], xmat[:, 2]),  # the normal: the geom's z axis
            np.arctan2(xmat[:, 3], xmat[:, 0]),  # the x axis
        )
        return np.concatenate([data.geom_xpos[self.ids, :2], yaw[:, None]], axis=1)

    def shapes(self, poses: np.ndarray) -> list[Shape]:
        return [
            Shape(k, (float(p[0]), float(p[1])), h, float(p[2]))
            for k, h, p in zip(self.kinds, self.halves, poses)
        ]


class Guide:
    """Keeps a :class:`GuideState`'s path up to date from the mirrored scene (module docstring):
    :meth:`update` once per iteration, before the task layer and the rollouts. ``field_source``:
    the planner's map, planned on too (None: the declared obstacles only)."""

    def __init__(
        self,
        state: GuideState,
        model: mujoco.MjModel,
        resolve: FrameResolver,
        field_source: FieldSource | None = None,
    ):
        cfg, scenario = state.cfg, state.scenario
        self.state, self.model, self.cfg = state, model, cfg
        self.field_source = field_source
        self._map: tuple[object, MapObstacles] | None = None  # the newest field, converted
        self.body = resolve(cfg.for_)
        self.goal = resolve(cfg.goal)
        self.site_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, SITE_BODY)
        self.data = mujoco.MjData(
            model
        )  # the reference pose: which planes face up, the goal height
        # an object the robot moves, not the robot or one of its bodies (a mobile base)
        guided = any(o.name == cfg.for_ and not o.fixed for o in scenario.world.objects)
        names = cfg.obstacles
        if names is None:
            names = list(WALL_NAMES) if scenario.world.arena else []
            names += [
                o.name
                for o in scenario.world.objects
                if not o.visual and o.name != cfg.for_ and (o.obstacle or guided)
            ]
        bodies = [resolve(n).id for n in names if n != cfg.for_]
        mujoco.mj_kinematics(model, self.data)
        self.geoms = ObstacleGeoms.of(model, self.data, bodies)
        self._reach = self.geoms.reach
        self._goal_z = float(self.goal.pos(self.data)[2])
        robot_body = resolve("robot")
        robot_r = footprint(model, robot_body.id, inscribed=False)
        self.radius = (
            cfg.radius if cfg.radius is not None else footprint(model, self.body.id, guided)
        )
        self.room = None
        if cfg.room != "none":
            self.room = Room(cfg.room, robot_r, self.radius + robot_r, cfg.gap)
        self.plan_fn = METHODS[cfg.method]
        self._planned: Snapshot | None = None  # what the current (or pending) path is for
        self._pending: Snapshot | None = None
        self._result: tuple[Snapshot, PathResult] | None = None
        self._cv = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="guide", daemon=True)
        self._thread.start()

    def snapshot(self, data: mujoco.MjData) -> Snapshot:
        """The scene in ``data`` (the mirror's, its kinematics done) as the guide plans on it."""
        return Snapshot(
            self.geoms.poses(data),
            self.body.pos(data)[:2].copy(),
            self.goal.pos(data)[:2].copy(),
            self._latest_map(),
        )

    def _latest_map(self) -> MapObstacles | None:
        """The map's newest field as the guide reads it, converted once per field; None without
        one, or for a 3-D field (an arm's workspace: the guide plans in the plane)."""
        latest = self.field_source.latest() if self.field_source is not None else None
        if latest is None or latest.dims != 2:
            return None
        if self._map is None or self._map[0] is not latest:
            values = latest.values.detach().cpu().numpy()
            origin = (float(latest.origin[0]), float(latest.origin[1]))
            obstacles = MapObstacles(values, origin, float(latest.resolution), latest.outside)
            self._map = (latest, obstacles)
        return self._map[1]

    def update(self, data: mujoco.MjData, wait: bool) -> None:
        """Take a finished path (``wait``: lock-step, waiting for the one requested last), ask
        for a new one if the scene changed, and put the sub-goal ``lookahead`` along the path
        beyond the guided body."""
        snap = self.snapshot(data)
        first = self._planned is None
        self._take(wait=wait)
        if self._needs_plan(snap):
            self._submit(snap)
            if first:  # the first path is computed before the first iteration plans
                self._take(wait=True)
        self._place_subgoal(snap)

    def extras(self) -> dict[str, float]:
        """What the observers may read: ``guide`` 1 while a path exists, 0 when blocked, and
        ``guide_length``, the path's length in metres (inf when blocked)."""
        st = self.state
        return {
            "guide": float(st.exists),
            "guide_length": st.path.length if st.exists else math.inf,
        }

    def corners(self) -> np.ndarray | None:
        """``[N, 3]`` the current path's corners at the goal's height, for viewers; None when
        there is no path."""
        points = self.state.points
        if points is None:
            return None
        z = np.full((len(points), 1), self._goal_z)
        return np.concatenate([points, z], axis=1)

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        self._thread.join(timeout=5.0)

    def _needs_plan(self, snap: Snapshot) -> bool:
        if self._pending is not None:  # one at a time; the next update compares again
            return False
        last = self._planned
        if last is None or snap.moved(last, self._reach, self.cfg.replan_move):
            return True
        if snap.field is not last.field and self._crossed(snap.field):
            return True
        if self.state.points is None:  # blocked: again once the body has moved two cells on
            moved = float(np.linalg.norm(snap.start - last.start))
            return moved > 2 * self.cfg.resolution
        off, _ = project_point(snap.start, self.state.points)
        return off > self.cfg.replan_distance

    def _crossed(self, field: MapObstacles | None) -> bool:
        """Whether the path may change on a new map ``field``: it passes closer than the body's
        radius to an obstacle of it, or there is no path or no map (a map may clear the way)."""
        points = self.state.points
        if field is None or points is None:
            return True
        dense = resample(points, self.cfg.resolution / 2)
        return bool((field.distance(dense) < self.radius).any())

    def _submit(self, snap: Snapshot) -> None:
        with self._cv:
            self._pending = snap
            self._planned = snap
            self._cv.notify_all()

    def _take(self, wait: bool) -> None:
        with self._cv:
            if wait:
                while self._pending is not None and self._result is None:
                    self._cv.wait()
            if self._result is None:
                return
            snap, result = self._result
            self._result, self._pending = None, None
        st = self.state
        st.points = result.points
        st.exists = result.points is not None
        st.path = PathTensors.of(result, snap.goal)
        st.version += 1
        if result.points is None:
            log.info(
                "guide: no path for %s to %s (%s)", self.cfg.for_, self.cfg.goal, result.reason
            )
        else:
            log.debug(
                "guide: path %d of %.2f m, %d corners",
                st.version,
                result.length,
                len(result.points),
            )

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._closed and (self._pending is None or self._result is not None):
                    self._cv.wait()
                if self._closed:
                    return
                snap = self._pending
            result = self.plan_fn(
                self.geoms.shapes(snap.poses),
                snap.start,
                snap.goal,
                self.cfg.resolution,
                self.radius + self.cfg.inflate,
                self.room,
                snap.field,
            )
            with self._cv:
                self._result = (snap, result)
                self._cv.notify_all()

    def _place_subgoal(self, snap: Snapshot) -> None:
        """The site ``lookahead`` m along the path beyond the body's nearest point on it (the
        goal itself when there is no path), at the goal's height."""
        st = self.state
        if st.points is None:
            xy = snap.goal
        else:
            _, s = project_point(snap.start, st.points)
            xy = point_at(st.points, s + self.cfg.lookahead)
        self.model.body_pos[self.site_body] = (xy[0], xy[1], self._goal_z)
