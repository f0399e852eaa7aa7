"""The planner's model state as one vector (``mj_getState``'s full physics), the joints the
mirror writes into it, and the sizes a world's state must have to fit it (:class:`StateSizes`,
which the planner checks a world's first state against and ``m3p2i layout`` prints)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np


def free_joint(model: mujoco.MjModel, body: str) -> int:
    """The id of body ``body``'s free joint (StopIteration if it has none)."""
    b = model.body(body).id
    return next(
        j
        for j in range(model.njnt)
        if model.jnt_bodyid[j] == b and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
    )


def state_size(model: mujoco.MjModel) -> int:
    return mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)


def get_full_state(
    model: mujoco.MjModel, data: mujoco.MjData, out: np.ndarray | None = None
) -> np.ndarray:
    """The full physics state vector [nstate] (mjSTATE_FULLPHYSICS), as mujoco.rollout expects."""
    out = np.empty(state_size(model)) if out is None else out
    mujoco.mj_getState(model, data, out, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return out


@dataclass(frozen=True)
class StateSizes:
    """The array sizes of a ``state`` that fits a model."""

    nq: int
    nv: int
    na: int
    nmocap: int

    @classmethod
    def of(cls, model: mujoco.MjModel) -> StateSizes:
        return cls(nq=model.nq, nv=model.nv, na=model.na, nmocap=model.nmocap)

    def mismatches(self, values: Mapping[str, Any]) -> list[str]:
        """One message per array of ``values`` (``qpos``, ``qvel``, ``act``, ``mocap_pos``,
        ``mocap_quat``) whose size differs from these sizes, naming both; empty when all fit."""
        out = []
        for name, size, what in (
            ("qpos", self.nq, "nq"),
            ("qvel", self.nv, "nv"),
            ("act", self.na, "na"),
        ):
            got = np.asarray(values[name]).size
            if got != size:
                out.append(f"{name} has {got} values, the scenario's model has {what} = {size}")
        for name, width in (("mocap_pos", 3), ("mocap_quat", 4)):
            shape = list(np.shape(values[name]))
            if int(np.prod(shape)) != self.nmocap * width:
                out.append(
                    f"{name} has shape {shape}, the scenario's model has nmocap = "
                    f"{self.nmocap} (shape [{self.nmocap}, {width}])"
                )
        return out
