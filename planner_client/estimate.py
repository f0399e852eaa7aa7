"""State estimation of the free bodies (the scenario's objects) from their received poses.

A simulated world sends exact poses and velocities. A robot's world knows its objects from
perception: poses with noise, and often no velocity at all. ``planner.estimate`` makes the
mirror filter the poses (an exponential filter: ``p ← w·p_new + (1 − w)·p``, quaternions
blended the same way and renormalised) and, with ``object_velocities: from_poses``, replace the
received velocities by finite differences of the filtered poses, filtered again: linear
velocity in the world frame, angular velocity in the body's frame (MuJoCo's free-joint
convention), from ``mju_subQuat``. A jump faster than ``max_speed`` is a teleport (a disturbance,
a cube put back by hand): the filters restart at the new pose, velocity 0.
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.scenario import EstimateConfig


class FreeBodyEstimator:
    """Filters the free joints' ``qpos`` (7 each) and, when asked, estimates their ``qvel``
    (6 each) in place of the received ones."""

    def __init__(self, model: mujoco.MjModel, cfg: EstimateConfig):
        self.cfg = cfg
        free = [j for j in range(model.njnt)
                if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        self.qadr = np.array([model.jnt_qposadr[j] for j in free], dtype=int)   # [F]
        self.vadr = np.array([model.jnt_dofadr[j] for j in free], dtype=int)    # [F]
        self._pos = np.zeros((len(free), 3))       # filtered poses
        self._quat = np.zeros((len(free), 4))
        self._vel = np.zeros((len(free), 6))       # filtered velocities (linear, angular)
        self._time: float | None = None

    @property
    def active(self) -> bool:
        cfg = self.cfg
        return bool(len(self.qadr)) and (cfg.pose_filter < 1.0 or cfg.velocity_filter < 1.0
                                         or cfg.object_velocities == "from_poses")

    def __call__(self, time: float, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state to mirror: ``qpos [nq]`` with the free bodies' poses filtered, ``qvel [nv]``
        with their velocities estimated (``from_poses``) or as received."""
        qpos, qvel = np.array(qpos, dtype=float), np.array(qvel, dtype=float)
        pos = np.stack([qpos[a:a + 3] for a in self.qadr])                      # [F, 3]
        quat = np.stack([qpos[a + 3:a + 7] for a in self.qadr])                 # [F, 4]
        dt = None if self._time is None else time - self._time
        if dt is None or dt <= 0:            # the first state, or a new episode: start afresh
            self._pos[:], self._quat[:], self._vel[:] = pos, quat, 0.0
        else:
            self._advance(pos, quat, dt)
        self._time = time
        for i, (a, v) in enumerate(zip(self.qadr, self.vadr)):
            qpos[a:a + 3], qpos[a + 3:a + 7] = self._pos[i], self._quat[i]
            if self.cfg.object_velocities == "from_poses":
                qvel[v:v + 6] = self._vel[i]
        return qpos, qvel

    def _advance(self, pos: np.ndarray, quat: np.ndarray, dt: float) -> None:
        w, wv = self.cfg.pose_filter, self.cfg.velocity_filter
        prev_pos, prev_quat = self._pos.copy(), self._quat.copy()
        teleport = np.linalg.norm(pos - prev_pos, axis=1) / dt > self.cfg.max_speed
        # the same rotation either way: blend towards the nearer of q and -q
        sign = np.where(np.sum(quat * prev_quat, axis=1) < 0, -1.0, 1.0)[:, None]
        self._pos[:] = w * pos + (1 - w) * prev_pos
        blended = w * sign * quat + (1 - w) * prev_quat
        self._quat[:] = blended / np.linalg.norm(blended, axis=1, keepdims=True)
        raw = np.zeros_like(self._vel)
        raw[:, :3] = (self._pos - prev_pos) / dt
        for i in range(len(raw)):
            mujoco.mju_subQuat(raw[i, 3:], self._quat[i], prev_quat[i])
        raw[:, 3:] /= dt
        self._vel[:] = wv * raw + (1 - wv) * self._vel
        self._pos[teleport], self._quat[teleport], self._vel[teleport] = (
            pos[teleport], quat[teleport], 0.0)
