"""The state mirror: the planner's MjData, overwritten by each state the world sends.

Not part of the planning problem: it is where a received state becomes the rollouts' initial
state, plus the velocity estimate of world-driven (mocap) bodies that the rollouts predict.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from planner_client.model_state import free_joint, get_full_state
from planner_client.tracking import FreeBodyEstimator, MocapEstimator, filters_poses
from shared.protocol import State
from shared.scenario import TrackingConfig
from shared.scene import STATE_FIELDS, set_state


@dataclass
class MocapState:
    """World-driven bodies: ``pos [nmocap, 3]``, ``quat [nmocap, 4]``, ``vel [nmocap, 3]``.

    mjSTATE_FULLPHYSICS (the rollouts' initial state) does not include mocap poses, so they
    travel beside it and are set in every rollout thread's MjData.
    """

    pos: np.ndarray
    quat: np.ndarray
    vel: np.ndarray

    @property
    def moving(self) -> bool:
        return bool(np.any(self.vel))


class Mirror:
    """The planner's MjData, overwritten by each received state (full physics state).

    It also estimates the velocity of every mocap body (objects the world moves: scripted or dynamic
    obstacles) from the last two states, for the constant-velocity prediction of paper Eq. 22. A
    jump faster than ``max_speed`` is a teleport (a disturbance), not motion: velocity 0. With
    ``tracking`` (``planner.tracking``), the free bodies' and the mocap bodies' poses are
    filtered and their velocities estimated from them (:mod:`planner_client.tracking`). The free
    objects named in ``planar`` (``planner.model.objects.<name>.planar``) are laid flat
    (:func:`flatten`).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        max_speed: float = 5.0,
        tracking: TrackingConfig | None = None,
        planar: Sequence[str] = (),
    ):
        self.model = model
        self.planar = [_free_joint(model, name) for name in planar]
        cfg = tracking or TrackingConfig()
        estimator = FreeBodyEstimator(model, cfg)
        self.estimator = estimator if estimator.active else None
        self.mocap_estimator = (
            MocapEstimator(model, cfg) if model.nmocap and filters_poses(cfg) else None
        )
        self.data = mujoco.MjData(model)
        self.x0 = np.zeros(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        self.max_speed = max_speed
        self.received_qpos = np.zeros(model.nq)  # the last state's qpos as received [nq]
        self.mocap_vel = np.zeros((model.nmocap, 3))
        self._prev_pos = np.zeros((model.nmocap, 3))
        self._prev_time: float | None = None

    def mocap(self) -> MocapState | None:
        """Poses and estimated velocities of the mocap bodies (None when the model has none)."""
        if not self.model.nmocap:
            return None
        return MocapState(self.data.mocap_pos, self.data.mocap_quat, self.mocap_vel)

    def _estimate_mocap_velocity(self, time: float) -> None:
        pos = self.data.mocap_pos
        if self._prev_time is not None and time > self._prev_time:
            with np.errstate(over="ignore"):  # over a tiny time step: inf, zeroed just below
                vel = (pos - self._prev_pos) / (time - self._prev_time)
            vel[np.linalg.norm(vel, axis=1) > self.max_speed] = 0.0
            self.mocap_vel[:] = vel
        elif self._prev_time is not None:  # time went back: a new episode
            self.mocap_vel[:] = 0.0
        self._prev_pos[:] = pos
        self._prev_time = time

    def apply(self, state: State) -> np.ndarray:
        """Copy ``state`` in, recompute kinematics, return the rollout initial state [nstate]."""
        m, d = self.model, self.data
        arrays = {name: getattr(state, name) for name in STATE_FIELDS}
        # before any filter: a held object is measured here (planner_client.attach)
        self.received_qpos = np.asarray(arrays["qpos"], dtype=float)
        mocap_vel = None
        if (
            self.estimator is not None
            and arrays["qpos"].shape == (m.nq,)
            and arrays["qvel"].shape == (m.nv,)
        ):  # (a misfit is set_state's to refuse)
            arrays["qpos"], arrays["qvel"] = self.estimator(
                state.time, arrays["qpos"], arrays["qvel"]
            )
        if (
            self.mocap_estimator is not None
            and np.size(arrays["mocap_pos"]) == 3 * m.nmocap
            and np.size(arrays["mocap_quat"]) == 4 * m.nmocap
        ):
            arrays["mocap_pos"], arrays["mocap_quat"], mocap_vel = self.mocap_estimator(
                state.time, arrays["mocap_pos"], arrays["mocap_quat"]
            )
        if self.planar and arrays["qpos"].shape == (m.nq,) and arrays["qvel"].shape == (m.nv,):
            arrays["qpos"], arrays["qvel"] = arrays["qpos"].copy(), arrays["qvel"].copy()
            for qadr, vadr in self.planar:
                flatten(m, arrays["qpos"], arrays["qvel"], qadr, vadr)
        try:
            set_state(m, d, arrays)
        except ValueError as exc:
            raise ValueError(f"state.{exc}") from None
        d.time = state.time
        if mocap_vel is not None:
            self.mocap_vel[:] = mocap_vel
        elif m.nmocap:
            self._estimate_mocap_velocity(state.time)
        return self.refresh()

    def refresh(self) -> np.ndarray:
        """Recompute kinematics after ``data`` changed; return the rollout start state [nstate]."""
        mujoco.mj_forward(self.model, self.data)
        return get_full_state(self.model, self.data, self.x0)


def _free_joint(model: mujoco.MjModel, body: str) -> tuple[int, int]:
    """qpos and qvel addresses of body ``body``'s free joint."""
    j = free_joint(model, body)
    return int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])


def flatten(
    model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, qadr: int, vadr: int
) -> None:
    """Lay a free object flat, in place: its height the model's start height (``qpos0``), its
    orientation the yaw of the received one, its z, roll and pitch velocities zero. For a
    planning model whose object does not rest on the floor (``planner.model.exclude:
    [[world, obj]]``, ``gravcomp``): the world's box sinks, tilts and rocks on its soft floor
    contacts by centimetres and degrees, and with no floor to right it the planner's box kept
    that tilt through the whole horizon (the closed loop failed every trial; tested on
    push_pull, 2026-12-01)."""
    qpos[qadr + 2] = model.qpos0[qadr + 2]
    w, x, y, z = qpos[qadr + 3 : qadr + 7]
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    qpos[qadr + 3 : qadr + 7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    qvel[vadr + 2 : vadr + 5] = 0.0
