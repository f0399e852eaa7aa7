"""The simulated world: the scenario's MuJoCo model stepped under the latest command.

One implementation of :class:`server.interface.World` (a hardware bridge is another:
:class:`server.bridge.Bridge`). Everything network-facing lives in :mod:`server.app`; the
success test and time-out (:mod:`server.judge`) are judged here, with the physics.
"""

from __future__ import annotations

import mujoco
import numpy as np

from server.disturbances import Disturbances, ObjectHandle
from server.interface import Outcome, World, WorldState
from server.judge import EpisodeJudge
from server.sensors import RangeSensors
from shared.frames import FrameResolver
from shared.geometry import select_axes
from shared.scans import Scan
from shared.scenario import Scenario
from shared.scene import reset_data

__all__ = ["Outcome", "SimWorld"]


class SimWorld(World):
    """Owns MjModel/MjData of the scenario; one :meth:`step` per command."""

    def __init__(self, scenario: Scenario, seed: int = 0):
        super().__init__(scenario, seed)
        self.data = mujoco.MjData(self.model)
        resolve = FrameResolver(self.model, self.robot.frame)
        self.judge = EpisodeJudge(scenario, resolve)
        self.battery = scenario.world.battery
        if self.battery:
            self._robot_frame = resolve("robot")
            self._charger = resolve(self.battery.charger)
        self.disturbances = Disturbances(
            self.model, resolve, scenario.world.randomize, scenario.world.disturbances
        )
        self.sensors = RangeSensors(scenario, self.model) if scenario.sensors else None
        self.reset()

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def ctrl(self) -> np.ndarray:
        return self.data.ctrl

    def reset(self) -> None:
        """Start pose (randomised from ``seed`` where the scenario says), status running."""
        reset_data(self.scenario, self.model, self.data)
        self.initial = self.disturbances.reset(self.data, np.random.default_rng(self.seed))
        mujoco.mj_forward(self.model, self.data)
        self.data.ctrl[:] = self.robot.safe_stop()  # what a safe stop holds before any command
        self.status = "running"
        self.judge.reset()
        if self.battery:
            self.extras["battery"] = self.battery.initial
        if self.sensors:
            self.sensors.reset()
            self.sensors.update(self.model, self.data)

    def move_object(self, name: str, pos, quat=None) -> dict:
        """Put scenario object ``name`` at ``pos`` (and ``quat``, w x y z) now, as a user's
        disturbance (``control`` op ``move``); returns the event to log. A ValueError says why
        not: a robot body, the arena, or a name the scenario does not have."""
        objects = [o.name for o in self.scenario.world.objects]
        if name not in objects:
            known = any(
                mujoco.mj_name2id(self.model, kind, name) >= 0
                for kind in (mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_GEOM)
            )
            what = (
                f"{name!r} is part of the robot or the arena, not a scenario object"
                if known
                else f"unknown object {name!r}"
            )
            raise ValueError(f"{what}; objects that can be moved: {', '.join(objects) or 'none'}")
        pos = np.asarray(pos, float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"object {name!r}: pos must be 3 finite numbers, got {pos.tolist()}")
        ObjectHandle(self.model, name).set(self.data, pos, quat=quat)
        mujoco.mj_forward(self.model, self.data)
        event = {
            "object": name,
            "pos": pos.tolist(),
            "time": float(self.data.time),
            "source": "control",
        }
        if quat is not None:
            event["quat"] = (np.asarray(quat, float) / np.linalg.norm(quat)).tolist()
        return event

    def step(self, ctrl: np.ndarray) -> None:
        """Advance one timestep holding ``ctrl`` (clipped to the actuators' ranges)."""
        lo, hi = self.model.actuator_ctrlrange.T
        np.clip(ctrl, lo, hi, out=self.data.ctrl)
        self.events += self.disturbances.apply(self.data, self.extras)
        mujoco.mj_step(self.model, self.data)
        # mj_step leaves xpos/xmat from before its integration; the success test, the battery
        # and the summary must see the state that is published
        mujoco.mj_kinematics(self.model, self.data)
        if self.battery:
            self._step_battery()
        if self.sensors:
            self.sensors.update(self.model, self.data)
        self._check_episode()

    def _step_battery(self) -> None:
        """Thesis Eq. 4.1, per second of simulated time: charge near the charger, else drain."""
        d = select_axes(self._robot_frame.pos(self.data) - self._charger.pos(self.data), "xy")
        sign = 1.0 if np.linalg.norm(d) <= self.battery.radius else -1.0
        level = self.extras["battery"] + sign * self.battery.rate * self.dt
        self.extras["battery"] = float(np.clip(level, 0.0, 100.0))

    def _check_episode(self) -> None:
        self.status = self.judge.update(self.status, self.data, self.extras, self.data.time)

    def state(self) -> WorldState:
        d = self.data
        return WorldState(
            time=float(d.time),
            qpos=d.qpos.copy(),
            qvel=d.qvel.copy(),
            act=d.act.copy(),
            mocap_pos=d.mocap_pos.copy(),
            mocap_quat=d.mocap_quat.copy(),
        )

    def scans(self) -> list[Scan]:
        """The sensors' readings since the last call (server/sensors.py), oldest first."""
        return self.sensors.take() if self.sensors else []

    def outcome(self) -> Outcome:
        """Status and the success predicates' measures (e.g. final distance to the goal)."""
        return Outcome(
            self.status, float(self.data.time), self.judge.measures(self.data, self.extras)
        )
