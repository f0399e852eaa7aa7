"""What happens to the world besides the robot: randomised starts, scripted moves, moving
obstacles. Configured in the scenario's ``world.randomize`` / ``world.disturbances``.

Free objects are moved through their free joint (velocity zeroed); fixed objects are mocap
bodies moved through ``mocap_pos``/``mocap_quat``, so either way the change reaches the planner
in the next state message, as a real perturbation would.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from shared.frames import FrameResolver
from shared.predicates import WorldView
from shared.scenario import MoveConfig, PathConfig, RandomizeConfig


def _yaw_quat(deg: float) -> np.ndarray:
    half = math.radians(deg) / 2
    return np.array([math.cos(half), 0.0, 0.0, math.sin(half)])


class ObjectHandle:
    """Reads and writes one object's pose, whichever way it is simulated."""

    def __init__(self, model: mujoco.MjModel, name: str):
        body = model.body(name)
        self.mocap = int(model.body_mocapid[body.id])
        if self.mocap < 0:
            joint = int(model.body_jntadr[body.id])
            self.qpos = int(model.jnt_qposadr[joint])
            self.dof = int(model.jnt_dofadr[joint])

    def pos(self, data: mujoco.MjData) -> np.ndarray:
        return (
            data.mocap_pos[self.mocap] if self.mocap >= 0 else data.qpos[self.qpos : self.qpos + 3]
        )

    def set(self, data: mujoco.MjData, pos=None, yaw: float | None = None, quat=None) -> None:
        """Move to ``pos`` and turn to ``yaw`` (degrees about z) or ``quat`` (w, x, y, z,
        normalised here); a free object's velocity is zeroed."""
        if quat is not None:
            quat = np.asarray(quat, float) / np.linalg.norm(quat)
        elif yaw is not None:
            quat = _yaw_quat(yaw)
        if self.mocap >= 0:
            if pos is not None:
                data.mocap_pos[self.mocap] = pos
            if quat is not None:
                data.mocap_quat[self.mocap] = quat
            return
        if pos is not None:
            data.qpos[self.qpos : self.qpos + 3] = pos
        if quat is not None:
            data.qpos[self.qpos + 3 : self.qpos + 7] = quat
        data.qvel[self.dof : self.dof + 6] = 0.0


def path_length(cfg: PathConfig) -> float:
    """Metres from the first waypoint to the last (back to the first too when ``loop``)."""
    points = np.array(cfg.waypoints)
    if cfg.loop:
        points = np.vstack([points, points[:1]])
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def path_point(cfg: PathConfig, t: float) -> np.ndarray:
    """Position on the waypoint polyline after ``t`` seconds of motion at ``cfg.speed``."""
    points = np.array(cfg.waypoints)
    if cfg.loop:
        points = np.vstack([points, points[:1]])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    total = seg.sum()
    s = cfg.speed * max(t, 0.0)
    s = s % total if cfg.loop and total > 0 else min(s, total)
    i = int(np.searchsorted(np.cumsum(seg), s, side="right"))
    if i >= len(seg):
        return points[-1]
    start = s - (np.cumsum(seg)[i] - seg[i])
    return points[i] + (points[i + 1] - points[i]) * (start / seg[i] if seg[i] > 0 else 0.0)


class Disturbances:
    """Applies randomisation at reset and scripted moves/paths before each world step.

    Events (logged as ``disturbance``): a move's ``{object, pos, yaw, time}`` when it fires; a
    path's ``{object, pos, yaw: None, time, path: "start"}`` at the step it starts (the object
    jumps from its scenario ``pos`` to the first waypoint) and, without ``loop``, ``{...,
    path: "end"}`` at the step it reaches its last waypoint, where it then stays. A looping path
    logs its start only: one event per path and episode, not one per step."""

    def __init__(
        self,
        model: mujoco.MjModel,
        resolve: FrameResolver,
        randomize: tuple[RandomizeConfig, ...],
        disturbances: tuple[MoveConfig | PathConfig, ...],
    ):
        self.randomize = randomize
        self.moves = [
            (d, d.when.bind(resolve) if d.when else None)
            for d in disturbances
            if isinstance(d, MoveConfig)
        ]
        self.paths = [d for d in disturbances if isinstance(d, PathConfig)]
        names = {c.object for c in randomize} | {d.object for d in disturbances}
        self.handles = {n: ObjectHandle(model, n) for n in names}
        self._done: set[int] = set()
        self._held_since: dict[int, float] = {}  # move index -> when its `when` first held
        self._path_phase: dict[int, str] = {}  # path index -> "start" / "end" logged

    def reset(self, data: mujoco.MjData, rng: np.random.Generator) -> list[dict]:
        """Draw the randomised start poses; returns what was drawn, for the episode log."""
        self._done.clear()
        self._held_since.clear()
        self._path_phase.clear()
        drawn = []
        for c in self.randomize:
            h = self.handles[c.object]
            pos = h.pos(data).copy()
            if c.choose is not None:
                pos[:] = c.choose[rng.integers(len(c.choose))]
            for axis, rng_range in ((0, c.x), (1, c.y)):
                if rng_range is not None:
                    pos[axis] = rng.uniform(*rng_range)
            yaw = rng.uniform(*c.yaw) if c.yaw is not None else None
            h.set(data, pos, yaw)
            drawn.append({"object": c.object, "pos": pos.tolist(), "yaw": yaw})
        return drawn

    @staticmethod
    def _path_event(p: PathConfig, pos: np.ndarray, time: float, phase: str) -> dict:
        return {
            "object": p.object,
            "pos": [float(v) for v in pos],
            "yaw": None,
            "time": float(time),
            "path": phase,
        }

    def apply(self, data: mujoco.MjData, extras: dict[str, float]) -> list[dict]:
        """Before a step at ``data.time``: move path objects, fire due moves; returns events."""
        events = []
        for i, p in enumerate(self.paths):
            if data.time < p.start - 1e-9:  # as a move's `at`: float steps
                continue
            moved = max(data.time - p.start, 0.0)
            pos = path_point(p, moved)
            self.handles[p.object].set(data, pos)
            phase = self._path_phase.get(i)
            if phase is None:
                phase = self._path_phase[i] = "start"
                events.append(self._path_event(p, pos, data.time, phase))
            if phase == "start" and not p.loop and p.speed * moved >= path_length(p) - 1e-9:
                self._path_phase[i] = "end"
                events.append(self._path_event(p, pos, data.time, "end"))
        view = WorldView(data, extras)
        for i, (m, when) in enumerate(self.moves):
            if i in self._done or data.time < m.at - 1e-9:
                continue
            # kinematics (xpos) are those computed during the last step: one step old at most
            if when is not None and i not in self._held_since:
                if not when(view):
                    continue
                self._held_since[i] = float(data.time)
            if data.time < self._held_since.get(i, 0.0) + m.delay - 1e-9:
                continue
            self.handles[m.object].set(data, m.pos, m.yaw)
            self._done.add(i)
            events.append(
                {"object": m.object, "pos": m.pos, "yaw": m.yaw, "time": float(data.time)}
            )
        return events
