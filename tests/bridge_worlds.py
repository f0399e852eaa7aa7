"""User world classes for ``m3p2i-server --world tests.bridge_worlds:Class`` (test_bridge_world.py).

:class:`KinematicBase` is a bridge as a user writes one (docs/bridge.md), with a kinematic
stand-in for the robot: a holonomic base that moves exactly at the commanded velocity, where a
real bridge would call its SDK and read a motion-capture pose.
"""

from __future__ import annotations

import numpy as np

from server.bridge import Bridge
from server.interface import WorldError


class KinematicBase(Bridge):
    """The point robot of the navigation scenario as a perfect velocity-controlled base:
    ``ctrl`` = world-frame (vx, vy) in m/s; no contacts, no servo lag."""

    def __init__(self, scenario, seed=0):
        super().__init__(scenario, seed)
        if self.model.nu != 2 or self.model.nq < 2:
            raise WorldError(
                f"KinematicBase drives a point robot (nu=2), the scenario "
                f"{scenario.name!r} has nu={self.model.nu}"
            )
        self.velocity = np.zeros(2)

    def reset(self) -> None:
        self.velocity = np.zeros(2)  # a new episode starts at rest
        super().reset()

    def actuate(self, ctrl: np.ndarray) -> None:
        self.velocity = ctrl[:2].copy()  # a real base: sdk.send_velocity(...)

    def sense(self) -> None:
        # a real base: the newest motion-capture pose; here, where the velocity took it
        self.data.qpos[:2] += self.velocity * self.dt
        self.data.qvel[:2] = self.velocity


class RecordingBase(KinematicBase):
    """:class:`KinematicBase` that keeps every control it sent, for the safety checks."""

    def __init__(self, scenario, seed=0):
        self.sent: list[np.ndarray] = []
        super().__init__(scenario, seed)

    def actuate(self, ctrl: np.ndarray) -> None:
        self.sent.append(ctrl.copy())
        super().actuate(ctrl)


class LosingTrack(RecordingBase):
    """:class:`RecordingBase` whose motion capture loses the robot after five steps."""

    def sense(self) -> None:
        if self._steps > 5:
            raise WorldError("motion capture lost the base")
        super().sense()


class NotAWorld:
    """A class that is no :class:`server.interface.World` (for the ``--world`` error)."""


class Unfinished(Bridge):
    """A bridge that forgot ``sense`` (for the ``--world`` error)."""

    def actuate(self, ctrl: np.ndarray) -> None:
        pass
