"""The base of a world the server does not simulate: a real robot, another simulator.

A subclass implements two methods: :meth:`Bridge.actuate` sends a control to the robot,
:meth:`Bridge.sense` writes the newest measurements into ``self.data`` (the scenario model's
``qpos``/``qvel``/``mocap_pos``/``mocap_quat``, SI units, world frame). Everything else the
server needs comes from here: the scenario's start state for whatever is not measured, the
clock (periods of ``dt``), the success test and time-out of the scenario's ``episode`` section
judged on the measured state, the safe stop. A bridge whose scenario declares ``sensors:``
overrides :meth:`server.interface.World.scans` too: its real lidar's and cameras' readings
(docs/bridge.md, "Sensors"). ``m3p2i-server --world package.module:Class``
serves it with the handshake, sessions, watchdog, rate loop and episode log of the simulated
world (docs/bridge.md has a worked example).
"""

from __future__ import annotations

from abc import abstractmethod

import mujoco
import numpy as np

from server.interface import Outcome, World, WorldState
from server.judge import EpisodeJudge
from shared.frames import FrameResolver
from shared.scenario import Scenario
from shared.scene import reset_data


class Bridge(World):
    """A world whose state is measured, not simulated.

    ``self.data`` is a ``mujoco.MjData`` of the scenario's model holding the published state:
    :meth:`reset` sets it to the scenario's start (objects where the YAML puts them), then
    :meth:`sense` overwrites what the robot and perception measure. Its kinematics are
    recomputed after each :meth:`sense` (the success test reads body positions), never its
    dynamics: nothing here simulates.

    Time is the number of steps times ``dt``: the server's real-time loop calls :meth:`step`
    every ``dt`` of wall-clock time, so the clock follows the wall clock (paused while the
    world is paused). Build the connection to the robot in ``__init__`` (after
    ``super().__init__``), and raise :class:`server.interface.WorldError` with the reason when
    it cannot be made.
    """

    def __init__(self, scenario: Scenario, seed: int = 0):
        super().__init__(scenario, seed)
        self.data = mujoco.MjData(self.model)
        self.judge = EpisodeJudge(scenario, FrameResolver(self.model, self.robot.frame))
        self._ctrl = self.robot.safe_stop()
        self._steps = 0

    @abstractmethod
    def actuate(self, ctrl: np.ndarray) -> None:
        """Send ``ctrl`` ``[nu]`` (already clipped to the actuators' ranges, in their units and
        frames: docs/bridge.md) to the robot, which holds it until the next call. Return at
        once: the server keeps the period."""

    @abstractmethod
    def sense(self) -> None:
        """Write the newest measurements into ``self.data`` (``qpos``, ``qvel``, ``mocap_pos``,
        ``mocap_quat``; ``self.extras`` for named scalars such as ``battery``). Finite values
        only: an unknown velocity is 0 or an estimate, never NaN."""

    @property
    def time(self) -> float:
        return self._steps * self.dt

    @property
    def ctrl(self) -> np.ndarray:
        return self._ctrl

    def reset(self) -> None:
        """Time 0, status ``running``, the safe control sent (the robot holds still until the
        first command), the scenario's start state overwritten by the first measurements. A
        robot is not moved back to the start: put it there before the episode (or write where
        it stands as the scenario's ``robot.qpos``)."""
        reset_data(self.scenario, self.model, self.data)
        self._steps = 0
        self._ctrl = self.robot.safe_stop()
        self.actuate(self._ctrl)
        self.status = "running"
        self.judge.reset()
        self._sense()

    def step(self, ctrl: np.ndarray) -> None:
        """Send ``ctrl`` (clipped), count one period, read the measurements and judge them."""
        self._ctrl = self.clip(ctrl)
        self.actuate(self._ctrl)
        self._steps += 1
        self._sense()
        self.status = self.judge.update(self.status, self.data, self.extras, self.time)

    def stop(self) -> None:
        """The safe control, sent now (zero velocity; a gripper keeps its command)."""
        self._ctrl = self.safe_command()
        self.actuate(self._ctrl)

    def state(self) -> WorldState:
        d = self.data
        return WorldState(
            time=self.time,
            qpos=d.qpos.copy(),
            qvel=d.qvel.copy(),
            act=d.act.copy(),
            mocap_pos=d.mocap_pos.copy(),
            mocap_quat=d.mocap_quat.copy(),
        )

    def outcome(self) -> Outcome:
        return Outcome(self.status, self.time, self.judge.measures(self.data, self.extras))

    def _sense(self) -> None:
        self.sense()
        self.data.time = self.time
        # the success test and the viewer read body poses: forward kinematics of the measured
        # state (mocap bodies included), no dynamics
        mujoco.mj_kinematics(self.model, self.data)
