"""The planner's model of the scenario: compiled MuJoCo model with sensors, objectives, mirror.

Built once at start-up from the same YAML as the server's world: objectives are validated
against the term registry and the model, every sensor they need is added to the spec, and the
result is compiled. :class:`Mirror` copies each received state into this model.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from shared.config import ConfigError, ErrorLog, Section
from shared.frames import FrameResolver
from shared.protocol import State
from shared.robots import RobotSpec, get_robot
from shared.scenario import Scenario
from shared.scene import build_spec, compile_model, get_full_state, obstacle_names
from planner_client.costs import Objective, TermContext, build_objective
from planner_client.mppi import MPPIConfig
from planner_client.sensors import SensorLayout, SensorRequest, add_sensors


@dataclass
class PlanningProblem:
    scenario: Scenario
    robot: RobotSpec
    model: mujoco.MjModel              # with the sensors of every objective
    objectives: dict[str, Objective]
    layout: SensorLayout
    robot_pos: SensorRequest           # the robot frame's position, for diagnostics
    actuators: list[str]
    resolve: FrameResolver


def build_problem(scenario: Scenario, extra_sensors: list[SensorRequest] = ()) -> PlanningProblem:
    robot = get_robot(scenario.robot.model)
    spec = build_spec(scenario)
    base = compile_model(scenario, spec.copy())
    resolve = FrameResolver(base, robot.frame)
    actuators = actuator_names(base)
    objectives = build_objectives(scenario, resolve, actuators)
    robot_pos = SensorRequest("framepos", "robot")
    requests = [robot_pos, *extra_sensors] + [r for o in objectives.values() for r in o.sensors()]
    add_sensors(spec, requests, resolve)
    model = compile_model(scenario, spec)
    return PlanningProblem(scenario, robot, model, objectives, SensorLayout(model, requests),
                           robot_pos, actuators, FrameResolver(model, robot.frame))


def actuator_names(model: mujoco.MjModel) -> list[str]:
    """Actuator names in control-vector order."""
    return [model.actuator(i).name for i in range(model.nu)]


def build_objectives(scenario: Scenario, resolve: FrameResolver,
                     actuators: list[str]) -> dict[str, Objective]:
    """Every objective of the scenario, checked against the term registry and the model; the
    errors of all objectives are raised together."""
    ctx = TermContext(scenario.source, resolve, obstacle_names(scenario), actuators)
    errors = ErrorLog()
    objectives = {name: errors.call(build_objective, name, cfg, ctx)
                  for name, cfg in scenario.objectives.items()}
    errors.raise_if_any()
    return objectives


def mppi_config(sc: Scenario, m: mujoco.MjModel) -> MPPIConfig:
    """MPPIConfig from ``planner.mppi`` of scenario ``sc``, defaults filled from model ``m``.

    Defaults: bounds = the actuators' ctrlrange, noise_sigma = a quarter of each range.
    """
    lo, hi = m.actuator_ctrlrange.T
    limited = m.actuator_ctrllimited.astype(bool)
    u_min = tuple(float(v) if lim else -math.inf for v, lim in zip(lo, limited))
    u_max = tuple(float(v) if lim else math.inf for v, lim in zip(hi, limited))
    sigma = tuple(float((b - a) / 4) if lim else 1.0 for a, b, lim in zip(lo, hi, limited))
    values = dict(horizon=sc.planner.horizon, nu=m.nu, noise_sigma=sigma, u_min=u_min, u_max=u_max)
    s = Section(sc.planner.mppi, sc.source, "planner.mppi")
    names = {f.name for f in dataclasses.fields(MPPIConfig)} - {"horizon", "nu"}
    for key, value in sc.planner.mppi.items():
        if key not in names:
            raise s.error(key, "unknown planner parameter", value, f"one of: {', '.join(sorted(names))}")
        values[key] = tuple(value) if isinstance(value, list) else value
    try:
        return MPPIConfig(**values)
    except (ValueError, TypeError) as exc:
        raise ConfigError(sc.source, "planner.mppi", str(exc)) from None


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

    It also estimates the velocity of every mocap body (objects the world moves: scripted or
    dynamic obstacles) from the last two states, for the constant-velocity prediction of Eq. 22.
    A jump faster than ``max_speed`` is a teleport (a disturbance), not motion: velocity 0.
    """

    def __init__(self, model: mujoco.MjModel, max_speed: float = 5.0):
        self.model = model
        self.data = mujoco.MjData(model)
        self.x0 = np.zeros(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        self.max_speed = max_speed
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
            vel = (pos - self._prev_pos) / (time - self._prev_time)
            vel[np.linalg.norm(vel, axis=1) > self.max_speed] = 0.0
            self.mocap_vel[:] = vel
        elif self._prev_time is not None:      # time went back: a new episode
            self.mocap_vel[:] = 0.0
        self._prev_pos[:] = pos
        self._prev_time = time

    def apply(self, state: State) -> np.ndarray:
        """Copy ``state`` in, recompute kinematics, return the rollout initial state [nstate]."""
        m, d = self.model, self.data
        for name, value, size in (("qpos", state.qpos, m.nq), ("qvel", state.qvel, m.nv),
                                  ("act", state.act, m.na), ("mocap_pos", state.mocap_pos, m.nmocap * 3),
                                  ("mocap_quat", state.mocap_quat, m.nmocap * 4)):
            if value.size != size:
                raise ValueError(f"state.{name} has {value.size} values, the model needs {size}")
            getattr(d, name).flat[:] = value.ravel()
        d.time = state.time
        if m.nmocap:
            self._estimate_mocap_velocity(state.time)
        mujoco.mj_forward(m, d)
        return get_full_state(m, d, self.x0)
