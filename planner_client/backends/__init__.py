"""Rollout backends: what the motion planner calls to roll out its sampled control sequences.

A backend takes one initial state and ``[S, T, nu]`` control sequences and returns the sensors
the cost terms read, ``sensordata [S, T, nsensordata]`` as a torch tensor on its device, in the
planner's dtype (float64). Two implementations:

- ``mujoco`` (default): ``mujoco.rollout``'s persistent thread pool on the CPU
  (:class:`~planner_client.backends.mujoco_pool.MujocoPoolBackend`).
- ``warp``: MuJoCo Warp (MJWarp), every sample a Warp "world", stepped together on a GPU or, slowly,
  on the CPU device (:class:`~planner_client.backends.warp.WarpBackend`; the ``m3p2i[gpu]`` extra).

Chosen by ``planner.backend`` in the scenario or ``m3p2i-planner --backend/--device``.
"""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np
import torch

from shared.config import ConfigError


class RolloutBackend(Protocol):
    """The interface :class:`~planner_client.motion.MotionPlanner` rolls out through."""

    name: str
    device: torch.device  # where sensordata lives, and so the costs and M3P2I update

    def set_mocap(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Mocap poses ``[nmocap, 3]``, ``[nmocap, 4]`` every rollout starts from."""

    def sensors(
        self, x0: np.ndarray, control: torch.Tensor, mocap_path: np.ndarray | None = None
    ) -> torch.Tensor:
        """Roll out ``control [S, T, nu]`` from the full physics state ``x0 [nstate]``; return
        ``sensordata [S, T, nsensordata]`` after each step (as ``mujoco.rollout`` records it).
        With ``mocap_path [T, nmocap, 3]`` the mocap bodies are placed there at each step."""

    def read_sensors(self, read: np.ndarray | None) -> None:
        """Only the sensors ``read`` (ids in the model) need to be right in the sensordata of
        the next rollouts (None: all): a backend may skip computing the others."""

    def close(self) -> None:
        """Release threads and device memory."""


def make_backend(
    name: str,
    model: mujoco.MjModel,
    *,
    samples: int,
    horizon: int,
    nthread: int = 0,
    device: str = "cuda:0",
    nconmax: int | None = None,
    njmax: int | None = None,
    source: str = "",
) -> RolloutBackend:
    """The backend ``name`` (``mujoco`` or ``warp``) for the planner's ``model``.

    ``samples`` x ``horizon`` size the warp backend's buffers up front (its "worlds"); ``source``
    is the scenario file, named in errors. Raises :class:`ConfigError` for an unknown backend,
    a missing ``m3p2i[gpu]`` extra, an unavailable device, or a model beyond MJWarp's limits.
    """
    if name == "mujoco":
        from planner_client.backends.mujoco_pool import MujocoPoolBackend

        return MujocoPoolBackend(model, nthread)
    if name == "warp":
        from planner_client.backends.warp import WarpBackend

        return WarpBackend(
            model,
            samples=samples,
            horizon=horizon,
            device=device,
            nconmax=nconmax,
            njmax=njmax,
            source=source,
        )
    raise ConfigError(source, "planner.backend", "unknown rollout backend", name, "mujoco or warp")
