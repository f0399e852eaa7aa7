"""The planner's model of the scenario: compiled MuJoCo model with sensors, objectives, mirror.

Built once at start-up from the same YAML as the server's world: objectives are validated against
the term registry and the model, every sensor they need is added to the spec, and the result is
compiled. :class:`~planner_client.mirror.Mirror` copies each received state into this model.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import torch

from planner_client.attach import add_attach_welds
from planner_client.costs import JointInfo, Objective, RolloutBatch, TermContext, build_objective
from planner_client.costs.base import FieldSlot, FieldSource
from planner_client.costs.objective import check_term_values
from planner_client.guide import GuideState, add_site
from planner_client.model_state import free_joint
from planner_client.mppi import MPPIConfig
from planner_client.plugins import import_plugins
from planner_client.sensors import SensorColumns, SensorRequest, add_sensors
from planner_client.spheres import SITE_PREFIX, add_sphere_sites, robot_spheres
from shared.config import ConfigError, ErrorLog
from shared.frames import FrameResolver
from shared.robots import RobotSpec
from shared.scenario import PlanningModel, Scenario
from shared.scene import WALL_NAMES, build_spec, compile_model, initial_data


@dataclass
class PlanningProblem:
    scenario: Scenario
    robot: RobotSpec
    model: mujoco.MjModel  # with the sensors of every objective
    objectives: dict[str, Objective]
    columns: SensorColumns  # where each sensor request is in sensordata
    robot_pos: SensorRequest  # the robot frame's position, for diagnostics
    actuators: list[str]
    resolve: FrameResolver
    guide: GuideState | None = None  # the scenario's guide: its path and sub-goal site
    # the planner's map as its terms and guide read it: connect the map updater to it
    field_source: FieldSlot = field(default_factory=FieldSlot)
    # sensors no objective lists, read by their caller: computed in every rollout
    extra_sensors: tuple[SensorRequest, ...] = ()


def robot_joints(scenario: Scenario, model: mujoco.MjModel) -> dict[str, JointInfo]:
    """The robot's hinge and slide joints (the objects have only free joints), in qpos order,
    with their ranges and start positions."""
    start = initial_data(scenario, model).qpos
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    out = {}
    for j in range(model.njnt):
        if int(model.jnt_type[j]) not in (hinge, slide):
            continue
        lo, hi = model.jnt_range[j]
        out[model.joint(j).name] = JointInfo(
            range=(float(lo), float(hi)) if model.jnt_limited[j] else None,
            hinge=int(model.jnt_type[j]) == hinge,
            start=float(start[model.jnt_qposadr[j]]),
        )
    return out


def build_problem(scenario: Scenario, extra_sensors: list[SensorRequest] = ()) -> PlanningProblem:
    """The planner's model of ``scenario`` and its objectives, its perceived objects left out
    (:func:`planner_scenario`: only the scans show them); ``problem.scenario`` is
    that view of the scenario. ``extra_sensors``: sensors no objective lists, for a caller that
    reads the rollouts' sensordata itself; a :class:`MotionPlanner` computes them too."""
    scenario = planner_scenario(scenario)
    robot = scenario.robot.spec
    spec = build_spec(scenario)
    # planner.timestep: the rollouts step (and hold each control) this long; the world's
    # physics is unchanged, and the world plays the plan at its own rate
    spec.option.timestep = scenario.planner.step(scenario.world)
    apply_planning_model(spec, scenario.planner.model, scenario.source)
    guide = None
    if scenario.guide is not None:
        add_site(spec)
        guide = GuideState(scenario.guide, scenario)
    base = compile_model(scenario, spec.copy())
    resolve = FrameResolver(base, robot.frame)
    if guide is not None:
        resolve.checked(guide.cfg.for_, scenario.source, "guide.for")
        resolve.checked(guide.cfg.goal, scenario.source, "guide.goal")
    actuators = [actuator_names(base)[i] for i in own_actuators(scenario, base)]
    field_source = FieldSlot()
    objectives = build_objectives(scenario, resolve, actuators, guide, field_source)
    robot_pos = SensorRequest("framepos", "robot")
    requests = [robot_pos, *extra_sensors] + [r for o in objectives.values() for r in o.sensors()]
    frames = {r.obj for r in requests}
    if any(f.startswith(f"site:{SITE_PREFIX}") for f in frames):  # a term reads the spheres
        add_sphere_sites(spec, robot_spheres(base, resolve, robot), frames)
    add_sensors(spec, requests, resolve)
    model = compile_model(scenario, spec)
    tune_planning_model(model, scenario.planner.model)
    return PlanningProblem(
        scenario,
        robot,
        model,
        objectives,
        SensorColumns.of_model(model, requests),
        robot_pos,
        actuators,
        FrameResolver(model, robot.frame),
        guide,
        field_source,
        tuple(extra_sensors),
    )


def check_terms(problem: PlanningProblem, device: torch.device | str = "cpu") -> None:
    """Every term of the problem's objectives evaluated once, and a ConfigError naming each one
    that raises or returns anything but a float64 tensor ``[S, T]`` on ``device``
    (:func:`~planner_client.costs.objective.check_term_values`): at the planner's start-up and
    by its check, before anything plans.

    The batch is 2 samples over the planner's horizon, every step the sensor values of the
    scenario's start state (``initial_data``: the planning model's own, its sensors computed)
    and the robot's safe control: real values, so a term that divides by a distance sees the
    start's, not zeros; a horizon of the planner's, since a term may depend on it (a step's
    time); 2 samples and not 1, so that a value of shape ``[T]`` or ``[1, T]`` does not pass.
    Not a rollout: that would cost one, run the backend before its first iteration and, on a
    GPU, compile kernels for this batch size; this reads the model's data once and draws
    nothing from the planner's sampler, so a seeded episode plans as it would without it."""
    samples, steps = 2, problem.scenario.planner.horizon
    data = initial_data(problem.scenario, problem.model)
    start = torch.as_tensor(data.sensordata, dtype=torch.float64, device=device)
    safe = torch.as_tensor(problem.robot.safe_stop(), dtype=torch.float64, device=device)
    batch = RolloutBatch(
        start.repeat(samples, steps, 1),  # contiguous like a rollout's, which an expanded
        # tensor is not: in-place operations on its views would fail here and not in a rollout
        safe.repeat(samples, steps, 1),
        problem.columns,
        float(problem.model.opt.timestep),
    )
    check_term_values(problem.objectives, batch)


_SOLVERS = {
    "Newton": mujoco.mjtSolver.mjSOL_NEWTON,
    "CG": mujoco.mjtSolver.mjSOL_CG,
    "PGS": mujoco.mjtSolver.mjSOL_PGS,
}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}
_INTEGRATORS = {
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
}

_GEOM_TYPES = {
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
}


def apply_planning_model(spec: mujoco.MjSpec, cfg: PlanningModel, source: str) -> None:
    """``planner.model`` on the planner's spec (the world's is never touched); a body of
    ``exclude`` that the model lacks raises ConfigError naming the pair, as does an object of
    ``objects`` without a free joint. The per-DOF values of ``objects`` are set on the compiled
    model (:func:`tune_planning_model`): a spec's joint has one value for all its DOFs."""
    opt = spec.option
    for key, table in (("solver", _SOLVERS), ("cone", _CONES), ("integrator", _INTEGRATORS)):
        if getattr(cfg, key) is not None:
            setattr(opt, key, table[getattr(cfg, key)])
    for key in ("iterations", "ls_iterations", "tolerance", "noslip_iterations"):
        if getattr(cfg, key) is not None:
            setattr(opt, key, getattr(cfg, key))
    if cfg.condim is not None:
        for geom in spec.geoms:
            geom.condim = cfg.condim
    bodies = [b.name for b in spec.bodies]
    for i, (a, b) in enumerate(cfg.exclude):
        for name in (a, b):
            if name not in bodies:
                raise ConfigError(
                    source,
                    f"planner.model.exclude[{i}]",
                    "unknown body",
                    name,
                    f"one of: {', '.join(bodies)}",
                )
        spec.add_exclude(bodyname1=a, bodyname2=b)
    for name, obj in cfg.objects.items():
        body = spec.body(name)
        free = [j for j in body.joints if j.type == mujoco.mjtJoint.mjJNT_FREE] if body else []
        if not free:
            known = [
                b.name
                for b in spec.bodies
                if any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in b.joints)
            ]
            raise ConfigError(
                source,
                f"planner.model.objects.{name}",
                "not a free object of the model",
                name,
                "one of: " + (", ".join(known) or "(none)"),
            )
        if obj.gravcomp is not None:
            body.gravcomp = obj.gravcomp
    for name, shape in cfg.geoms.items():
        geom = spec.geom(name)
        if geom is None:
            raise ConfigError(
                source,
                f"planner.model.geoms.{name}",
                "unknown geom",
                name,
                "one of: " + ", ".join(g.name for g in spec.geoms if g.name),
            )
        if shape.type is not None:
            geom.type = _GEOM_TYPES[shape.type]
        if shape.size is not None:
            geom.size = list(shape.size) + [0.0] * (3 - len(shape.size))
        if shape.pos is not None:
            geom.pos = list(shape.pos)
    try:
        add_attach_welds(spec, cfg.attach)
    except KeyError as exc:
        i, key, name, known = exc.args[0]
        raise ConfigError(
            source,
            f"planner.model.attach[{i}].{key}",
            "unknown body",
            name,
            f"one of: {', '.join(known)}",
        ) from None


def tune_planning_model(model: mujoco.MjModel, cfg: PlanningModel) -> None:
    """The per-DOF joint values of ``planner.model.objects`` (damping, frictionloss, armature)
    on the compiled planner model, after :func:`apply_planning_model` on its spec."""
    for name, obj in cfg.objects.items():
        joint = free_joint(model, name)
        dofs = slice(model.jnt_dofadr[joint], model.jnt_dofadr[joint] + 6)
        for key in ("damping", "frictionloss", "armature"):
            if getattr(obj, key) is not None:
                getattr(model, f"dof_{key}")[dofs] = getattr(obj, key)


def actuator_names(model: mujoco.MjModel) -> list[str]:
    """Actuator names in control-vector order."""
    return [model.actuator(i).name for i in range(model.nu)]


def own_actuators(scenario: Scenario, model: mujoco.MjModel) -> list[int]:
    """The actuators this planner commands, in its control order: all of the model's, or in a
    team's scenario its own robot's (planner_client.team)."""
    if not scenario.team:
        return list(range(model.nu))
    names = actuator_names(model)
    return [names.index(n) for n in scenario.robot.spec.ctrl_names]


def build_objectives(
    scenario: Scenario,
    resolve: FrameResolver,
    actuators: list[str],
    guide: GuideState | None = None,
    field_source: FieldSource | None = None,
) -> dict[str, Objective]:
    """Every objective of the scenario, checked against the term registry (the scenario's
    ``plugins:`` imported first) and the model; the errors of all objectives are raised
    together. ``field_source``: the planner's map, for the terms that read it."""
    import_plugins(scenario.plugins, Path(scenario.source).parent, scenario.source)
    ctx = TermContext(
        scenario.source,
        resolve,
        obstacle_names(scenario),
        actuators,
        robot_joints(scenario, resolve.model),
        guide=guide,
        robot=scenario.robot.spec,
        field_source=field_source,
    )
    errors = ErrorLog()
    objectives = {
        name: errors.call(build_objective, name, cfg, ctx)
        for name, cfg in scenario.objectives.items()
    }
    errors.raise_if_any()
    return objectives


def mppi_config(sc: Scenario, m: mujoco.MjModel) -> MPPIConfig:
    """MPPIConfig from ``planner.mppi`` of scenario ``sc``, defaults filled from model ``m``.

    Defaults: bounds = the actuators' ctrlrange, noise_sigma = a quarter of each range.
    """
    own = own_actuators(sc, m)
    lo, hi = m.actuator_ctrlrange[own].T
    limited = m.actuator_ctrllimited[own].astype(bool)
    u_min = tuple(float(v) if lim else -math.inf for v, lim in zip(lo, limited))
    u_max = tuple(float(v) if lim else math.inf for v, lim in zip(hi, limited))
    sigma = tuple(float((b - a) / 4) if lim else 1.0 for a, b, lim in zip(lo, hi, limited))
    values = dict(
        horizon=sc.planner.horizon, nu=len(own), noise_sigma=sigma, u_min=u_min, u_max=u_max
    )
    values.update(sc.planner.mppi.given())  # checked at load (shared/scenario/mppi.py)
    try:
        cfg = MPPIConfig(**values)
    except (ValueError, TypeError) as exc:  # what needs the model: lengths against its actuators
        raise ConfigError(sc.source, "planner.mppi", str(exc)) from None
    return cfg


def obstacle_names(scenario: Scenario) -> list[str]:
    """Bodies a collision cost should keep the robot away from: walls and non-visual obstacles."""
    names = list(WALL_NAMES) if scenario.world.arena else []
    names += [o.name for o in scenario.world.objects if o.obstacle and not o.visual]
    return names


def planner_scenario(scenario: Scenario) -> Scenario:
    """The scenario as the planner knows it: its world without the perceived objects
    (``world.objects[].perceived``), nor the randomised starts and disturbances that move them
    (the world's own business); ``scenario`` itself when none is perceived. Its hash is the
    file's: both processes still loaded the same scenario."""
    perceived = {o.name for o in scenario.world.objects if o.perceived}
    if not perceived:
        return scenario
    w = scenario.world
    world = dataclasses.replace(
        w,
        objects=tuple(o for o in w.objects if not o.perceived),
        randomize=tuple(r for r in w.randomize if r.object not in perceived),
        disturbances=tuple(d for d in w.disturbances if d.object not in perceived),
    )
    return dataclasses.replace(scenario, world=world)
