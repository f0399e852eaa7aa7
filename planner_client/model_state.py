"""The planner's model state as one vector (``mj_getState``'s full physics), and the joints
the mirror writes into it."""

from __future__ import annotations

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
