"""State estimation of the bodies a world measures by perception, from their received poses.

A simulated world sends exact poses and velocities. A robot's world knows its objects from
perception: poses with noise, and often no velocity at all. ``planner.tracking`` makes the
mirror filter the poses (an exponential filter: ``p ← w·p_new + (1 − w)·p``, quaternions
blended the same way and renormalised; with ``predict``, ``p`` is first moved on by its filtered
velocity over the time since, an alpha-beta filter that does not trail a body moving at constant
velocity by ``(1 − w)/w`` states) and, with ``object_velocities: from_poses``, replace the
received velocities by finite differences of the filtered poses, filtered again: linear
velocity in the world frame, angular velocity in the body's frame (MuJoCo's free-joint
convention), from ``mju_subQuat``. A jump faster than ``max_speed`` is a teleport (a disturbance,
a cube put back by hand): the filters restart at the new pose, velocity 0. A filtered velocity
slower than ``still_speed`` is the filters' noise, not motion: it is taken as 0. A state with
the time stamp of the previous one is the same measurement again and changes nothing; an older
one begins a new episode.

The same filters serve the free bodies (the scenario's movable objects, :class:`FreeBodyEstimator`)
and the mocap bodies (its fixed objects, which a world may still move: a table, a scripted
obstacle), whose velocity feeds the constant-velocity prediction of paper Eq. 22: from raw
differences of a tracker's poses, a table 5 mm noisy "moved" at up to 1 m/s and the rollouts
threw it, and the cube on it, about (pick_place under the lab profile).
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.scenario import TrackingConfig


class PoseFilter:
    """Exponential filters of ``N`` poses and of their finite-difference velocities.

    ``pos [N, 3]``, ``quat [N, 4]``: the filtered poses; ``vel [N, 6]``: the filtered
    velocities (linear in the world frame, angular in the body's).
    """

    def __init__(self, n: int, cfg: TrackingConfig):
        self.cfg = cfg
        self.pos = np.zeros((n, 3))
        self.quat = np.zeros((n, 4))
        self.vel = np.zeros((n, 6))
        self._time: float | None = None

    def __call__(self, time: float, pos: np.ndarray, quat: np.ndarray) -> None:
        """Take the poses measured at ``time`` (``pos [N, 3]``, ``quat [N, 4]``)."""
        dt = None if self._time is None else time - self._time
        if dt == 0:  # the same measurement again (a duplicate): no news
            return
        if dt is None or not dt > 0:  # the first state, or a new episode: start afresh
            self.pos[:], self.quat[:], self.vel[:] = pos, quat, 0.0
        else:
            self._advance(pos, quat, dt)
        self._time = time

    def _advance(self, pos: np.ndarray, quat: np.ndarray, dt: float) -> None:
        cfg = self.cfg
        w, wv = cfg.pose_filter, cfg.velocity_filter
        prev_pos, prev_quat = self.pos.copy(), self.quat.copy()
        teleport = np.linalg.norm(pos - prev_pos, axis=1) / dt > cfg.max_speed
        prior_pos, prior_quat = prev_pos, prev_quat
        if cfg.predict:  # the prior: the last pose moved on at the filtered velocity
            prior_pos = prev_pos + self.vel[:, :3] * dt
            prior_quat = prev_quat.copy()
            for i in range(len(prior_quat)):
                mujoco.mju_quatIntegrate(prior_quat[i], self.vel[i, 3:], dt)
        # the same rotation either way: blend towards the nearer of q and -q
        sign = np.where(np.sum(quat * prior_quat, axis=1) < 0, -1.0, 1.0)[:, None]
        self.pos[:] = w * pos + (1 - w) * prior_pos
        blended = w * sign * quat + (1 - w) * prior_quat
        self.quat[:] = blended / np.linalg.norm(blended, axis=1, keepdims=True)
        raw = np.zeros_like(self.vel)
        raw[:, :3] = (self.pos - prev_pos) / dt
        for i in range(len(raw)):
            mujoco.mju_subQuat(raw[i, 3:], self.quat[i], prev_quat[i])
        raw[:, 3:] /= dt
        self.vel[:] = wv * raw + (1 - wv) * self.vel
        self.pos[teleport], self.quat[teleport], self.vel[teleport] = (
            pos[teleport],
            quat[teleport],
            0.0,
        )

    def velocity(self) -> np.ndarray:
        """The filtered velocities ``[N, 6]``, those of bodies slower than ``still_speed`` 0."""
        out = self.vel.copy()
        out[np.linalg.norm(out[:, :3], axis=1) < self.cfg.still_speed] = 0.0
        return out


def filters_poses(cfg: TrackingConfig) -> bool:
    """Whether ``cfg`` changes received poses or velocities at all."""
    return (
        cfg.pose_filter < 1.0 or cfg.velocity_filter < 1.0 or cfg.object_velocities == "from_poses"
    )


class FreeBodyEstimator:
    """Filters the free joints' ``qpos`` (7 each) and, when asked, estimates their ``qvel``
    (6 each) in place of the received ones."""

    def __init__(self, model: mujoco.MjModel, cfg: TrackingConfig):
        self.cfg = cfg
        free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        self.qadr = np.array([model.jnt_qposadr[j] for j in free], dtype=int)  # [F]
        self.vadr = np.array([model.jnt_dofadr[j] for j in free], dtype=int)  # [F]
        self.filter = PoseFilter(len(free), cfg)

    @property
    def active(self) -> bool:
        return bool(len(self.qadr)) and filters_poses(self.cfg)

    def __call__(
        self, time: float, qpos: np.ndarray, qvel: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The state to mirror: ``qpos [nq]`` with the free bodies' poses filtered, ``qvel [nv]``
        with their velocities estimated (``from_poses``) or as received."""
        qpos, qvel = np.array(qpos, dtype=float), np.array(qvel, dtype=float)
        f = self.filter
        f(
            time,
            np.stack([qpos[a : a + 3] for a in self.qadr]),  # [F, 3]
            np.stack([qpos[a + 3 : a + 7] for a in self.qadr]),
        )  # [F, 4]
        vel = f.velocity()
        for i, (a, v) in enumerate(zip(self.qadr, self.vadr)):
            qpos[a : a + 3], qpos[a + 3 : a + 7] = f.pos[i], f.quat[i]
            if self.cfg.object_velocities == "from_poses":
                qvel[v : v + 6] = vel[i]
        return qpos, qvel


class MocapEstimator:
    """Filters the mocap bodies' received poses and estimates their linear velocities
    (``[nmocap, 3]``) from the filtered poses, for worlds that perceive them."""

    def __init__(self, model: mujoco.MjModel, cfg: TrackingConfig):
        self.cfg = cfg
        self.filter = PoseFilter(model.nmocap, cfg)

    def __call__(
        self, time: float, pos: np.ndarray, quat: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(pos [nmocap, 3], quat [nmocap, 4], vel [nmocap, 3])``: filtered, and estimated."""
        f = self.filter
        f(
            time,
            np.asarray(pos, dtype=float).reshape(-1, 3),
            np.asarray(quat, dtype=float).reshape(-1, 4),
        )
        return f.pos.copy(), f.quat.copy(), f.velocity()[:, :3]
