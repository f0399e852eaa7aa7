"""What a world (the simulator or a hardware bridge) must send and accept for a scenario, by name.

The wire carries bare arrays (``state.qpos [nq]``, ``command.ctrl [nu]``, ...) in MuJoCo's order
of the scenario's compiled model. :func:`bridge_layout` names every index of them: the joint,
component and unit of each ``qpos`` and ``qvel`` entry, the body of each mocap slot, the
actuator, range, unit and safe value of each ``ctrl`` entry, and the ``extras`` the world
simulates, the sensors whose readings ``state.scans`` carries. The model is the planner's: the
world's without its perceived objects, whose poses never travel. ``m3p2i layout SCENARIO``
prints it; the planner checks a world's first state against the same sizes
(:class:`planner_client.model_state.StateSizes`). Beside it, :func:`frame_names` lists the
frames a scenario may name (cost terms, observers, the success test, metrics): the robot's
bodies and sites, the objects, the arena's walls.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import mujoco

from planner_client.model_state import StateSizes
from planner_client.problem import planner_scenario
from shared.scenario import Scenario
from shared.scenario.sensors import LidarConfig, SensorConfig
from shared.scene import WALL_NAMES, compile_model

_FREE, _BALL, _SLIDE, _HINGE = (
    mujoco.mjtJoint.mjJNT_FREE,
    mujoco.mjtJoint.mjJNT_BALL,
    mujoco.mjtJoint.mjJNT_SLIDE,
    mujoco.mjtJoint.mjJNT_HINGE,
)
_JOINT_TYPE = {int(_FREE): "free", int(_BALL): "ball", int(_SLIDE): "slide", int(_HINGE): "hinge"}
_TARGET = {
    int(trn): target
    for trn, target in (
        (mujoco.mjtTrn.mjTRN_JOINT, ("joint", mujoco.mjtObj.mjOBJ_JOINT)),
        (mujoco.mjtTrn.mjTRN_JOINTINPARENT, ("joint", mujoco.mjtObj.mjOBJ_JOINT)),
        (mujoco.mjtTrn.mjTRN_TENDON, ("tendon", mujoco.mjtObj.mjOBJ_TENDON)),
        (mujoco.mjtTrn.mjTRN_SITE, ("site", mujoco.mjtObj.mjOBJ_SITE)),
        (mujoco.mjtTrn.mjTRN_BODY, ("body", mujoco.mjtObj.mjOBJ_BODY)),
        (mujoco.mjtTrn.mjTRN_SLIDERCRANK, ("slider-crank", mujoco.mjtObj.mjOBJ_SITE)),
    )
}


@dataclass(frozen=True)
class Coordinate:
    """One entry of ``qpos`` or ``qvel``.

    ``component``: ``x``/``y``/``z`` and ``qw``/``qx``/``qy``/``qz`` (a free joint's position and
    orientation), ``vx``/``vy``/``vz`` and ``wx``/``wy``/``wz`` (its velocities), ``position`` /
    ``velocity`` (a slide joint, along ``axis``), ``angle`` / ``rate`` (a hinge, about ``axis``).
    ``frame`` says how the value is expressed: ``world`` (a free joint's position and orientation
    of the body frame, and its linear velocity), ``body`` (angular velocity in the body's own
    frame, MuJoCo's convention for free and ball joints), ``parent`` (a ball joint's rotation from
    the body's rest orientation in its parent) or ``axis`` (a slide or hinge: along or about
    ``axis``, given in the body's frame, from the joint's zero). ``range`` is the joint's limit
    (``qpos`` of a limited slide or hinge only)."""

    index: int
    joint: str
    joint_type: str  # free | ball | slide | hinge
    body: str  # the body the joint moves (a scenario object's, for its free joint)
    component: str
    unit: str  # m, rad, quaternion (qpos); m/s, rad/s (qvel)
    frame: str  # world | body | parent | axis
    axis: tuple[float, float, float] | None = None
    range: tuple[float, float] | None = None


@dataclass(frozen=True)
class Activation:
    """One entry of ``act``: the internal state of an actuator with dynamics (a filter, an
    integrator)."""

    index: int
    actuator: str


@dataclass(frozen=True)
class MocapSlot:
    """Row ``index`` of ``mocap_pos [nmocap, 3]`` (m, world frame) and ``mocap_quat [nmocap, 4]``
    (w, x, y, z, world frame): a body the world moves (a fixed scenario object)."""

    index: int
    body: str
    scenario_object: bool  # a name under world.objects (else a mocap body of the robot's MJCF)


@dataclass(frozen=True)
class Control:
    """One entry of ``command.ctrl`` (and of each row of ``plan_ctrl``).

    ``target`` is what the actuator drives (``joint panda_joint1``, ``tendon gripper_width``,
    ``site base``, ``body robot``); ``range`` the control range (None: unlimited), outside which
    the world clips; ``safe`` the value of a safe stop, which ``holds_last`` actuators replace by
    their last command once one was applied (a gripper keeps its grip)."""

    index: int
    actuator: str
    target: str
    unit: str
    range: tuple[float, float] | None
    safe: float
    holds_last: bool


@dataclass(frozen=True)
class Extra:
    """A named scalar of ``state.extras`` that the scenario's world reports."""

    name: str
    unit: str
    range: tuple[float, float]
    description: str


@dataclass(frozen=True)
class Sensor:
    """A sensor whose readings ``state.scans`` carries (docs/protocol.md, "Scans"): ``shape``
    of its ``ranges`` (a lidar's ``[rays]``, a depth camera's ``[height, width]``), readings per
    world second, where it sits (``pos`` in ``frame``), its band of ranges (m) and its field of
    view (degrees: a lidar's sweep, a depth camera's vertical)."""

    name: str
    kind: str  # lidar | depth
    shape: tuple[int, ...]
    rate: float
    frame: str
    pos: tuple[float, float, float]
    range: tuple[float, float]
    fov: float


@dataclass(frozen=True)
class TeamRobot:
    """One robot of a team (``robots:``): its planner (``--robot NAME``) sends ``ctrl[ctrl]``
    as its ``command.ctrl``; its joints are ``qpos[qpos]`` and ``qvel[qvel]`` (start, stop)."""

    name: str
    ctrl: tuple[int, int]
    qpos: tuple[int, int]
    qvel: tuple[int, int]


def _team(scenario: Scenario, model: mujoco.MjModel) -> tuple[TeamRobot, ...]:
    """Each team robot's indices: its actuators and joints are named ``NAME/...``."""
    out = []
    for m in scenario.team:
        prefix = f"{m.name}/"
        acts = [a for a in range(model.nu) if model.actuator(a).name.startswith(prefix)]
        joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(prefix)]
        out.append(
            TeamRobot(
                m.name,
                (acts[0], acts[-1] + 1),
                (int(model.jnt_qposadr[joints[0]]), _ends(model.jnt_qposadr, model.nq, joints)),
                (int(model.jnt_dofadr[joints[0]]), _ends(model.jnt_dofadr, model.nv, joints)),
            )
        )
    return tuple(out)


def _ends(adr, size: int, joints: list[int]) -> int:
    """Where the last of ``joints``' coordinates end (the next joint's address, or ``size``)."""
    last = joints[-1]
    return int(adr[last + 1]) if last + 1 < len(adr) else size


@dataclass(frozen=True)
class BridgeLayout:
    """Every index of what a world sends (``state``) and accepts (``command``), by name."""

    scenario: str
    scenario_hash: str
    robot: str
    dt: float  # the scenario's world timestep (s)
    sizes: StateSizes
    nu: int
    qpos: tuple[Coordinate, ...]
    qvel: tuple[Coordinate, ...]
    act: tuple[Activation, ...]
    mocap: tuple[MocapSlot, ...]
    ctrl: tuple[Control, ...]
    extras: tuple[Extra, ...]
    sensors: tuple[Sensor, ...] = ()
    perceived: tuple[str, ...] = ()  # objects of the world the state does not carry
    # a team's robots: which indices of ctrl, qpos and qvel each one's planner owns
    team: tuple[TeamRobot, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain lists, dicts, strings and numbers (``--json``, for bridges in other languages)."""
        return asdict(self)


def bridge_layout(scenario: Scenario, model: mujoco.MjModel | None = None) -> BridgeLayout:
    """The layout of ``scenario``'s state and command, from the model they fit (compiled here
    unless given): the planner's, the world's without its perceived objects."""
    model = model if model is not None else compile_model(planner_scenario(scenario))
    robot = scenario.robot.spec
    objects = {o.name for o in scenario.world.objects}
    qpos, qvel = [], []
    for j in range(model.njnt):
        qpos += _qpos_rows(model, j)
        qvel += _qvel_rows(model, j)
    act = tuple(
        Activation(int(model.actuator_actadr[a]) + k, model.actuator(a).name)
        for a in range(model.nu)
        for k in range(int(model.actuator_actnum[a]))
    )
    mocap = sorted(
        (
            MocapSlot(int(model.body_mocapid[b]), model.body(b).name, model.body(b).name in objects)
            for b in range(model.nbody)
            if model.body_mocapid[b] >= 0
        ),
        key=lambda slot: slot.index,
    )
    safe = robot.safe_stop()
    ctrl = tuple(
        Control(
            index=a,
            actuator=model.actuator(a).name,
            target=_target(model, a),
            unit=robot.ctrl_units[a],
            range=(
                tuple(float(v) for v in model.actuator_ctrlrange[a])
                if model.actuator_ctrllimited[a]
                else None
            ),
            safe=float(safe[a]),
            holds_last=model.actuator(a).name in robot.hold_ctrl,
        )
        for a in range(model.nu)
    )
    return BridgeLayout(
        team=_team(scenario, model),
        scenario=scenario.name,
        scenario_hash=scenario.hash,
        robot=robot.name,
        dt=float(model.opt.timestep),
        sizes=StateSizes.of(model),
        nu=model.nu,
        qpos=tuple(qpos),
        qvel=tuple(qvel),
        act=act,
        mocap=tuple(mocap),
        ctrl=ctrl,
        extras=_extras(scenario),
        sensors=tuple(_sensor(c) for c in scenario.sensors),
        perceived=tuple(o.name for o in scenario.world.objects if o.perceived),
    )


def _extras(scenario: Scenario) -> tuple[Extra, ...]:
    """The state's extras beside the physics: the battery's charge, where the world has one."""
    b = scenario.world.battery
    if not b:
        return ()
    return (
        Extra(
            "battery",
            "%",
            (0.0, 100.0),
            f"charge level: rises by {b.rate:g} %/s within {b.radius:g} m (xy) of "
            f"{b.charger!r}, else falls by as much; starts at {b.initial:g}",
        ),
    )


def _sensor(c: SensorConfig) -> Sensor:
    """A scenario sensor as the layout lists it: its reading's shape and field of view."""
    lidar = isinstance(c, LidarConfig)
    shape = (c.rays,) if lidar else (c.height, c.width)
    return Sensor(
        c.name, c.kind, shape, c.rate, c.frame, c.pos, c.range, c.fov if lidar else c.fovy
    )


@dataclass(frozen=True)
class FrameName:
    """A frame a scenario may name (:mod:`shared.frames`): a body by its name, a site as
    ``site:NAME``, or ``robot``, the robot's own frame (``same_as`` the body or site it is).
    ``part``: ``robot`` (the robot's kinematic tree), ``object`` (a scenario object), ``arena``
    (a wall) or ``scene`` (a fixed body of the robot's model file, e.g. a table)."""

    name: str
    kind: str  # body | site
    part: str  # robot | object | arena | scene
    same_as: str | None = None


def frame_names(scenario: Scenario, model: mujoco.MjModel | None = None) -> tuple[FrameName, ...]:
    """Every frame name ``scenario``'s YAML may use, ``robot`` first, then the bodies and the
    sites in the model's order (compiled here unless given)."""
    model = model if model is not None else compile_model(scenario)
    robot = scenario.robot.spec
    objects = {o.name for o in scenario.world.objects}
    if robot.frame.startswith("site:"):
        own = int(model.site_bodyid[model.site(robot.frame[5:]).id])
    else:
        own = model.body(robot.frame).id
    robot_root = int(model.body_rootid[own])

    def part(body: int) -> str:
        name = model.body(body).name
        if name in objects:
            return "object"
        if name in WALL_NAMES:
            return "arena"
        for m in scenario.team:  # a team's robot: its bodies are named NAME/...
            if name.startswith(f"{m.name}/"):
                return f"robot {m.name}"
        return "robot" if int(model.body_rootid[body]) == robot_root else "scene"

    out = [
        FrameName(
            "robot",
            "site" if robot.frame.startswith("site:") else "body",
            "robot",
            same_as=robot.frame if robot.frame != "robot" else None,
        )
    ]
    out += [
        FrameName(model.body(b).name, "body", part(b))
        for b in range(1, model.nbody)
        if model.body(b).name and model.body(b).name != "robot"
    ]
    out += [
        FrameName(f"site:{model.site(i).name}", "site", part(int(model.site_bodyid[i])))
        for i in range(model.nsite)
        if model.site(i).name
    ]
    return tuple(out)


def _joint(model: mujoco.MjModel, j: int) -> tuple[str, str, str]:
    kind = _JOINT_TYPE[int(model.jnt_type[j])]
    return model.joint(j).name, kind, model.body(model.jnt_bodyid[j]).name


def _qpos_rows(model: mujoco.MjModel, j: int) -> list[Coordinate]:
    name, kind, body = _joint(model, j)
    start = int(model.jnt_qposadr[j])
    quat = [("qw", "quaternion"), ("qx", "quaternion"), ("qy", "quaternion"), ("qz", "quaternion")]
    if kind == "free":
        parts = [("x", "m"), ("y", "m"), ("z", "m")] + quat
        return [
            Coordinate(start + i, name, kind, body, c, u, "world") for i, (c, u) in enumerate(parts)
        ]
    if kind == "ball":
        return [
            Coordinate(start + i, name, kind, body, c, u, "parent") for i, (c, u) in enumerate(quat)
        ]
    axis = tuple(float(v) for v in model.jnt_axis[j])
    limit = tuple(float(v) for v in model.jnt_range[j]) if model.jnt_limited[j] else None
    component, unit = ("position", "m") if kind == "slide" else ("angle", "rad")
    return [Coordinate(start, name, kind, body, component, unit, "axis", axis=axis, range=limit)]


def _qvel_rows(model: mujoco.MjModel, j: int) -> list[Coordinate]:
    name, kind, body = _joint(model, j)
    start = int(model.jnt_dofadr[j])
    # MuJoCo's convention: a free joint's linear velocity is in the world frame, its angular
    # velocity (like a ball joint's) in the body's own frame
    angular = [("wx", "rad/s"), ("wy", "rad/s"), ("wz", "rad/s")]
    if kind == "free":
        parts = [("vx", "m/s"), ("vy", "m/s"), ("vz", "m/s")] + angular
        return [
            Coordinate(start + i, name, kind, body, c, u, "world" if i < 3 else "body")
            for i, (c, u) in enumerate(parts)
        ]
    if kind == "ball":
        return [
            Coordinate(start + i, name, kind, body, c, u, "body")
            for i, (c, u) in enumerate(angular)
        ]
    axis = tuple(float(v) for v in model.jnt_axis[j])
    component, unit = ("velocity", "m/s") if kind == "slide" else ("rate", "rad/s")
    return [Coordinate(start, name, kind, body, component, unit, "axis", axis=axis)]


def _target(model: mujoco.MjModel, a: int) -> str:
    kind, obj = _TARGET.get(int(model.actuator_trntype[a]), ("?", None))
    ident = int(model.actuator_trnid[a][0])
    name = mujoco.mj_id2name(model, obj, ident) if obj is not None and ident >= 0 else None
    return f"{kind} {name or ident}"
