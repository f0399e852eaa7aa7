"""The ``robots`` section: several robots on one world, each driven by its own planner.

Each robot is attached to the world under its name (``a/robot`` is robot ``a``'s body ``robot``,
``a/vel_x`` its actuator), in the section's order, so the world's control vector is the robots'
controls one after the other. The world sees the team as one robot (:func:`team_robot`); each
planner reads the scenario as its own robot's view (``Scenario.members``), in which ``robot``
names its own robot's frame and the robot's entry is merged over the top level, as a scenario
over its ``base:``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from shared.config import Section
from shared.robots import RobotSpec
from shared.scenario.robot import RobotConfig, read_robot

# what a robot's entry may declare for its own planner, beside its robot
MEMBER_KEYS = ("robot", "modes", "task", "observers", "plan", "planner")


@dataclass(frozen=True)
class Member:
    """One robot of a team: its name (the prefix of its bodies, joints and actuators) and its
    robot, the robot file's names prefixed."""

    name: str
    robot: RobotConfig


def read_team(s: Section) -> tuple[Member, ...]:
    """``robots:`` NAME: {robot: ..., and any of modes, task, observers, plan, planner}; at
    least two robots, names without ``/``."""
    if len(s.data) < 2:
        raise s.error("", "a team needs at least two robots", list(s.data), "NAME: {robot: ...}")
    team = []
    for name in s.data:
        entry = s.section(name)
        if not isinstance(name, str) or not name or "/" in name or name == "robot":
            raise s.error(name, "not a robot name", name, "a word without '/', not 'robot'")
        robot = read_robot(entry.section("robot"))
        for key in MEMBER_KEYS[1:]:
            entry.opt(key, None)
        entry.done()
        team.append(Member(name, dataclasses.replace(robot, spec=prefixed(robot.spec, name))))
    s.done()
    return tuple(team)


def prefixed(spec: RobotSpec, name: str) -> RobotSpec:
    """The robot file of a robot attached as ``name``: its frame, controls and bodies prefixed."""
    frame = spec.frame
    frame = f"site:{name}/{frame[5:]}" if frame.startswith("site:") else f"{name}/{frame}"
    return dataclasses.replace(
        spec,
        frame=frame,
        ctrl_names=tuple(f"{name}/{n}" for n in spec.ctrl_names),
        hold_ctrl=tuple(f"{name}/{n}" for n in spec.hold_ctrl),
        spheres=tuple((f"{name}/{body}", s) for body, s in spec.spheres),
    )


def team_robot(team: tuple[Member, ...]) -> RobotConfig:
    """The team as the world sees it: one robot whose controls are every robot's in turn (its
    frame, for ``robot`` in the top-level keys, the first robot's)."""
    specs = [m.robot.spec for m in team]
    spec = dataclasses.replace(
        specs[0],
        name="+".join(m.name for m in team),
        description=", ".join(f"{m.name}: {m.robot.model}" for m in team),
        ctrl_names=sum((s.ctrl_names for s in specs), ()),
        ctrl_units=sum((s.ctrl_units for s in specs), ()),
        safe_ctrl=sum((s.safe_ctrl for s in specs), ()),
        hold_ctrl=sum((s.hold_ctrl for s in specs), ()),
        spheres=sum((s.spheres for s in specs), ()),
    )
    return RobotConfig(model=spec.name, spec=spec)
