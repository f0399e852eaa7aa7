"""Batched forward simulation of sampled control sequences with ``mujoco.rollout``.

All S = N·K samples of an iteration run in one call, from the mirrored state, on a persistent
thread pool with one MjData per thread; outputs are preallocated once per (S, T). This is the
planner's physical limit: ``scripts/benchmark.py`` reports an iteration's time as a ratio to it.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from planner_client.sensors import SensorSwitch


class RolloutEngine:
    """Runs ``[S, T, nu]`` controls from one state; returns ``sensordata [S, T, nsensordata]``
    (a buffer reused by the next call). The costs read sensors only: the states along the
    rollouts, which ``mujoco.rollout`` always records, go to an array it allocates and nothing
    reads (a kept buffer for them measured no faster: their nstate is 5-51 numbers).

    With ``mocap_path`` the mocap bodies follow a given path during the rollouts (the per-step
    control vector is then [ctrl, mocap_pos], mujoco's state order): the planner's constant
    velocity prediction of moving obstacles (paper Eq. 22).
    """

    def __init__(self, model: mujoco.MjModel, nthread: int = 0):
        self.model = model
        self.nthread = nthread or os.cpu_count() or 1
        self.spec = int(mujoco.mjtState.mjSTATE_CTRL)
        self.mocap_spec = self.spec | int(mujoco.mjtState.mjSTATE_MOCAP_POS)
        self.nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self._datas = [mujoco.MjData(model) for _ in range(self.nthread)]
        self._pool = mj_rollout.Rollout(nthread=self.nthread)
        bodies = np.flatnonzero(model.body_mocapid >= 0)
        self._mocap_bodies = bodies[np.argsort(model.body_mocapid[bodies])]  # of mocap 0, 1, ...
        self._shape: tuple[int, int] | None = None
        self._variants: list[mujoco.MjModel] | None = None  # set_models: a model per rollout
        self._switch = SensorSwitch(model)
        self._read: np.ndarray | None = None  # the sensors computed (ids); None: all

    def _buffers(self, samples: int, horizon: int) -> None:
        if self._shape == (samples, horizon):
            return
        self._shape = (samples, horizon)
        self._models = [self.model] * samples
        self._x0 = np.zeros((samples, self.nstate))
        self._sensor = np.zeros((samples, horizon, self.model.nsensordata))
        self._full = np.zeros((samples, horizon, self.model.nu + 3 * self.model.nmocap))
        # ~10 chunks per thread balance the load without per-sample dispatch cost (mujoco's own
        # default; 25-sample chunks measured up to 1.6x slower on 2 cores)
        self._chunk = max(1, samples // (self.nthread * 10))

    def set_models(self, models: list[mujoco.MjModel] | None) -> None:
        """One model per rollout from now on (variants of the planner's model, the same sizes:
        ``mujoco.rollout`` takes a sequence); its length is the number of rollouts a
        :meth:`run` must have. None: the planner's model for every rollout."""
        self._variants = None if models is None else list(models)
        self._switch.only(self._models_rolled_out(), self._read)

    def read_sensors(self, read: np.ndarray | None) -> None:
        """Compute only the sensors ``read`` (ids in the model) in the rollouts from now on,
        the others' columns of sensordata left meaningless (:class:`SensorSwitch`); None: all.
        The model is the planner's own, so its other users (the mirror, the prediction of the
        start state) compute only these too: none of them reads sensors."""
        self._read = read
        self._switch.only(self._models_rolled_out(), read)

    def _models_rolled_out(self) -> list[mujoco.MjModel]:
        """The model, and each distinct variant of :meth:`set_models`."""
        unique = {id(m): m for m in self._variants or ()}
        unique[id(self.model)] = self.model
        return list(unique.values())

    def set_mocap(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Mocap poses [nmocap, 3], [nmocap, 4] to start every rollout from.

        mjSTATE_FULLPHYSICS, the rollouts' initial state, leaves mocap bodies out, and each
        rollout starts from a reset MjData, which takes its mocap poses from the model's
        ``body_pos`` / ``body_quat``: so those are what is set (in the planner's own model; the
        physics is unchanged).
        """
        self.model.body_pos[self._mocap_bodies] = pos
        self.model.body_quat[self._mocap_bodies] = quat

    def run(
        self, x0: np.ndarray, control: np.ndarray, mocap_path: np.ndarray | None = None
    ) -> np.ndarray:
        """Roll out ``control [S, T, nu]`` (float64) from ``x0 [nstate]`` and the poses of
        :meth:`set_mocap`; with ``mocap_path [T, nmocap, 3]`` the mocap bodies are placed there
        at each step instead (the same path for all samples)."""
        samples, horizon, nu = control.shape
        if nu != self.model.nu:
            raise ValueError(f"control has {nu} channels per step; the model needs {self.model.nu}")
        self._buffers(samples, horizon)
        self._x0[:] = x0
        spec = self.spec
        if mocap_path is not None:
            self._full[..., :nu] = control
            self._full[..., nu:] = mocap_path.reshape(1, horizon, -1)
            control, spec = self._full, self.mocap_spec
        models = self._models
        if self._variants is not None:
            if len(self._variants) != samples:
                raise ValueError(
                    f"{samples} rollouts for {len(self._variants)} models (set_models)"
                )
            models = self._variants
        self._pool.rollout(
            models,
            self._datas,
            self._x0,
            np.ascontiguousarray(control),
            control_spec=spec,
            skip_checks=True,
            nstep=horizon,
            state=None,
            sensordata=self._sensor,
            chunk_size=self._chunk,
        )
        return self._sensor

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None
