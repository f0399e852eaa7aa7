"""The default rollout backend: ``mujoco.rollout``'s persistent thread pool on the CPU."""

from __future__ import annotations

import numpy as np
import torch

from planner_client.rollout import RolloutEngine


class MujocoPoolBackend(RolloutEngine):
    """:class:`~planner_client.rollout.RolloutEngine` behind the backend interface: float64
    sensordata on the CPU, returned as a tensor over the engine's buffer (no copy)."""

    name = "mujoco"
    device = torch.device("cpu")

    def sensors(
        self, x0: np.ndarray, control: torch.Tensor, mocap_path: np.ndarray | None = None
    ) -> torch.Tensor:
        """``sensordata [S, T, nsensordata]`` of ``control [S, T, nu]`` rolled out from ``x0``;
        a view of a buffer the next call overwrites."""
        return torch.from_numpy(self.run(x0, control.numpy(), mocap_path))
