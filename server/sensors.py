"""The world's range sensors (the scenario's ``sensors:``): a 2-D lidar and a depth camera, cast
with MuJoCo's own ray tests (``mujoco.mj_multiRay``: headless, nothing rendered) from each
sensor's pose in the world's current kinematics; their readings are :class:`shared.scans.Scan`.

What a ray sees: the first collidable geom along it. The robot is never a return: the sensor's
own body is skipped, and a ray that meets another body of the robot (the tree of bodies its
frame hangs from) first is no return, as a robot's self-filter drops those points. Markers
(``visual`` objects: they collide with nothing) are seen through, and so is a geom drawn fully
transparent (MuJoCo's rays skip those). A hit nearer than the sensor's ``range`` min or beyond
its max is no return too, written as :func:`no_return`.

A sensor's readings fall due at whole multiples of 1/``rate`` world seconds from the episode's
start; each is taken at the first world state at or after its time, stamped with that state's
time and the sensor's pose then. The world keeps the newest :data:`MAX_PENDING` readings of
each sensor until the server takes them (:meth:`RangeSensors.take`) for the next state it
publishes.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from shared.frames import Frame, FrameResolver
from shared.scans import Scan, ray_directions
from shared.scenario import Scenario
from shared.scenario.sensors import WORLD_FRAME, DepthConfig, LidarConfig, SensorConfig

MAX_PENDING = 4  # readings of one sensor a state may carry (a slow planner's states)
_DUE = 1e-9  # world seconds: a reading due at t is taken at a step whose time rounds to t


def no_return(range_max: float) -> float:
    """The range the simulated world writes for a ray without a return: outside the band."""
    return float(range_max) + 1.0


@dataclass
class RangeSensor:
    """One sensor, resolved against the world's model."""

    cfg: SensorConfig
    frame: Frame | None  # None: fixed in the world
    offset: np.ndarray  # [3] the sensor's position in its frame, m
    turn: np.ndarray  # [3, 3] its axes (columns) in its frame
    template: Scan  # the reading's fixed fields; ranges of its shape
    rays: np.ndarray  # [M, 3] unit directions in the sensor's frame, ranges' C order
    exclude: int  # the body its rays skip (its own; -1: none)
    pending: deque[Scan] = field(default_factory=lambda: deque(maxlen=MAX_PENDING))
    due: int = 0  # the index of its next reading: due at due / rate world seconds


class RangeSensors:
    """The scenario's sensors in the world's ``model``: :meth:`update` after each world step
    (and at the start), :meth:`take` for each state published."""

    def __init__(self, scenario: Scenario, model: mujoco.MjModel):
        resolve = FrameResolver(model, scenario.robot.spec.frame)
        robot = resolve("robot")
        own = robot.id if robot.kind == mujoco.mjtObj.mjOBJ_BODY else model.site_bodyid[robot.id]
        robot_geoms = model.body_rootid[model.geom_bodyid] == model.body_rootid[own]
        collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        # a hit on these is no return: the robot's own geoms, and markers in a group of obstacles
        self.ignored = robot_geoms | ~collides
        self.groups = np.zeros(6, dtype=np.uint8)  # mjNGROUP: a ray sees the groups of obstacles
        self.groups[np.clip(model.geom_group[~self.ignored], 0, 5)] = 1
        self.sensors = [_resolve(cfg, resolve, model) for cfg in scenario.sensors]

    def reset(self) -> None:
        """The episode's start: readings due from time 0, none pending."""
        for s in self.sensors:
            s.due = 0
            s.pending.clear()

    def update(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Take the readings due at ``data.time`` (its kinematics computed)."""
        for s in self.sensors:
            if data.time + _DUE >= s.due / s.cfg.rate:
                s.pending.append(self.read(s, model, data))
                s.due = math.floor((data.time + _DUE) * s.cfg.rate) + 1

    def take(self) -> list[Scan]:
        """The readings taken since the last call, oldest first."""
        out = sorted((r for s in self.sensors for r in s.pending), key=lambda r: r.time)
        for s in self.sensors:
            s.pending.clear()
        return out

    def read(self, sensor: RangeSensor, model: mujoco.MjModel, data: mujoco.MjData) -> Scan:
        """``sensor``'s reading of ``data`` now."""
        if sensor.frame is None:
            pos, rot = np.zeros(3), np.eye(3)
        else:
            pos, rot = sensor.frame.pos(data), sensor.frame.rot(data)
        origin = pos + rot @ sensor.offset
        axes = rot @ sensor.turn
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, axes.reshape(-1))
        n = len(sensor.rays)
        geom = np.empty(n, dtype=np.int32)
        dist = np.empty(n)
        lo, hi = sensor.cfg.range
        vec = np.ascontiguousarray(sensor.rays @ axes.T).reshape(-1)
        mujoco.mj_multiRay(
            model, data, origin, vec, self.groups, 1, sensor.exclude, geom, dist, None, n, hi
        )
        seen = geom >= 0
        seen[seen] = ~self.ignored[geom[seen]]
        seen &= (dist >= lo) & (dist <= hi)
        ranges = np.where(seen, dist, no_return(hi)).reshape(sensor.template.ranges.shape)
        return replace(sensor.template, time=float(data.time), pos=origin, quat=quat, ranges=ranges)


def _resolve(cfg: SensorConfig, resolve: FrameResolver, model: mujoco.MjModel) -> RangeSensor:
    """``cfg`` in the world's model: its frame, its pose in it and its rays."""
    frame = None if cfg.frame == WORLD_FRAME else resolve(cfg.frame)
    exclude = -1
    if frame is not None:
        exclude = (
            frame.id if frame.kind == mujoco.mjtObj.mjOBJ_BODY else model.site_bodyid[frame.id]
        )
    lo, hi = cfg.range
    if isinstance(cfg, LidarConfig):
        fov = math.radians(cfg.fov)
        # all round: N rays 2π/N apart, none twice; a sector: its two edges included
        step = fov / cfg.rays if cfg.fov >= 360.0 else fov / max(cfg.rays - 1, 1)
        template = Scan(
            cfg.name,
            "lidar",
            0.0,
            np.zeros(3),
            np.array([1.0, 0.0, 0.0, 0.0]),
            np.zeros(cfg.rays),
            lo,
            hi,
            angle_min=-fov / 2 if cfg.rays > 1 else 0.0,
            angle_increment=step if cfg.rays > 1 else 0.0,
        )
    else:
        template = Scan(
            cfg.name,
            "depth",
            0.0,
            np.zeros(3),
            np.array([1.0, 0.0, 0.0, 0.0]),
            np.zeros((cfg.height, cfg.width)),
            lo,
            hi,
            fovy=cfg.fovy,
        )
    return RangeSensor(
        cfg=cfg,
        frame=frame,
        offset=np.asarray(cfg.pos, dtype=float),
        turn=_turn(cfg),
        template=template,
        rays=ray_directions(template).reshape(-1, 3),
        exclude=int(exclude),
    )


def _turn(cfg: SensorConfig) -> np.ndarray:
    """The sensor's axes (columns) in its frame: a lidar's are the frame's; a depth camera's
    turned by ``euler`` or towards ``look_at`` (its image's up towards the frame's +z, or its +x
    when looking straight up or down)."""
    if isinstance(cfg, DepthConfig) and cfg.euler is not None:
        quat, mat = np.zeros(4), np.zeros(9)
        mujoco.mju_euler2Quat(quat, np.radians(cfg.euler), "xyz")
        mujoco.mju_quat2Mat(mat, quat)
        return mat.reshape(3, 3)
    if isinstance(cfg, DepthConfig) and cfg.look_at is not None:
        z = np.subtract(cfg.look_at, cfg.pos)
        z /= np.linalg.norm(z)
        up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 1 - 1e-9 else np.array([1.0, 0.0, 0.0])
        y = -(up - (up @ z) * z)  # OpenCV's image y points down
        y /= np.linalg.norm(y)
        return np.stack([np.cross(y, z), y, z], axis=1)
    return np.eye(3)
