"""Robot models (MJCF shipped in this package) and the registry that scenarios name them by.

A robot MJCF is a complete model with the robot in its worldbody; the scene builder
(:mod:`shared.scene`) loads it as the base of the scenario's `mujoco.MjSpec` and adds the world.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROBOT_DIR = Path(__file__).parent


@dataclass(frozen=True)
class RobotSpec:
    """What the rest of the system needs to know about a robot model.

    Attributes:
        name: registry key, used as ``robot.model`` in scenario YAML.
        mjcf: MJCF file name inside ``shared/robots``.
        frame: body (or site, prefixed ``site:``) whose pose is "the robot" for costs/observers.
        description: one line for ``--help`` and error messages.
        ctrl_names: actuator names in control-vector order (checked against the MJCF).
        ctrl_units: the unit of each control, in ``ctrl_names`` order, for bridges
            (``m3p2i layout``): ``m/s``, ``rad/s``, ``m``, ``fraction`` (0..1), ``ignored``.
        safe_ctrl: the control that holds the robot still (zero velocity for velocity actuators);
            applied by the server when commands go stale, and by the planner when the task is
            done or has failed.
        hold_ctrl: actuators a safe stop leaves at their last command instead: a gripper keeps
            its grip (closing could grab a cube just released; opening would drop a held one).
            Their ``safe_ctrl`` value applies only before any command was received.
    """

    name: str
    mjcf: str
    frame: str
    description: str
    ctrl_names: tuple[str, ...]
    ctrl_units: tuple[str, ...]
    safe_ctrl: tuple[float, ...]
    hold_ctrl: tuple[str, ...] = ()

    @property
    def path(self) -> Path:
        return ROBOT_DIR / self.mjcf

    def safe_stop(self, last_ctrl: Sequence[float] | None = None) -> np.ndarray:
        """The control of a safe stop ``[nu]``: ``safe_ctrl``, with the ``hold_ctrl`` actuators
        at ``last_ctrl`` (the last command applied) when given. The one definition both the
        server (stale commands) and the planner (task done or failed) use."""
        ctrl = np.array(self.safe_ctrl, dtype=float)
        if last_ctrl is not None:
            hold = [self.ctrl_names.index(n) for n in self.hold_ctrl]
            ctrl[hold] = np.asarray(last_ctrl, dtype=float)[hold]
        return ctrl


ROBOTS: dict[str, RobotSpec] = {}


def register(spec: RobotSpec) -> RobotSpec:
    if spec.name in ROBOTS:
        raise ValueError(f"robot {spec.name!r} registered twice")
    if len(spec.ctrl_units) != len(spec.ctrl_names):
        raise ValueError(
            f"robot {spec.name!r}: {len(spec.ctrl_units)} ctrl_units for "
            f"{len(spec.ctrl_names)} ctrl_names; one unit per control"
        )
    ROBOTS[spec.name] = spec
    return spec


def get_robot(name: str) -> RobotSpec:
    try:
        return ROBOTS[name]
    except KeyError:
        raise KeyError(f"unknown robot {name!r}; registered: {', '.join(sorted(ROBOTS))}") from None


register(
    RobotSpec(
        name="point_robot",
        mjcf="point_robot.xml",
        frame="robot",
        description="omnidirectional point robot: velocity actuators on x and y (thesis code)",
        ctrl_names=("vel_x", "vel_y"),
        ctrl_units=("m/s", "m/s"),
        safe_ctrl=(0.0, 0.0),
    )
)

register(
    RobotSpec(
        name="point_robot_suction",
        mjcf="point_robot_suction.xml",
        frame="robot",
        description="point robot with the pull suction: world velocities vel_x, vel_y (m/s) and "
        "suction in [0, 1] (adhesion actuator, 250 N at 1)",
        ctrl_names=("vel_x", "vel_y", "suction"),
        ctrl_units=("m/s", "m/s", "fraction"),
        safe_ctrl=(0.0, 0.0, 0.0),
    )
)

register(
    RobotSpec(
        name="diff_drive",
        mjcf="diff_drive.xml",
        frame="robot",
        description="non-holonomic differential drive: body-frame forward speed (m/s) and yaw rate "
        "(rad/s); lateral_grip is the passive tyre grip, its control value is ignored",
        ctrl_names=("forward", "yaw_rate", "lateral_grip"),
        ctrl_units=("m/s", "rad/s", "ignored"),
        safe_ctrl=(0.0, 0.0, 0.0),
    )
)

register(
    RobotSpec(
        name="panda",
        mjcf="panda.xml",
        frame="site:grasp",
        description="Franka Emika Panda on the table: joint velocities j1..j7 (rad/s) and gripper "
        "opening width (m, 0 closed .. 0.08 open)",
        ctrl_names=("j1", "j2", "j3", "j4", "j5", "j6", "j7", "gripper"),
        ctrl_units=("rad/s",) * 7 + ("m",),
        safe_ctrl=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        hold_ctrl=("gripper",),
    )
)

register(
    RobotSpec(
        name="mobile_panda",
        mjcf="mobile_panda.xml",
        frame="site:grasp",
        description="holonomic base (0.6 x 0.5 m) carrying the Panda: world-frame base velocities "
        "base_vx, base_vy (m/s) and yaw rate base_wz (rad/s), the Panda's joint velocities j1..j7 "
        "(rad/s) and gripper opening width (m, 0 closed .. 0.08 open)",
        ctrl_names=("base_vx", "base_vy", "base_wz", "j1", "j2", "j3", "j4", "j5", "j6", "j7")
        + ("gripper",),
        ctrl_units=("m/s", "m/s", "rad/s") + ("rad/s",) * 7 + ("m",),
        safe_ctrl=(0.0,) * 11,
        hold_ctrl=("gripper",),
    )
)
