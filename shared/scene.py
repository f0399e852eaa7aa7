"""Build a scenario's MuJoCo model with ``mujoco.MjSpec``.

The server and the planner call the same builder on the same YAML, so they compile the same
world, but for the perceived objects, which the planner leaves out (planner_client.problem).
The planner adds sensors to its copy of the spec (what its costs need); sensors do not change
the dynamics, so the mirrored state stays valid.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from shared.scenario import ObjectConfig, Scenario

_GEOM = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
}
WALL_NAMES = ("wall_north", "wall_south", "wall_east", "wall_west")


def build_spec(scenario: Scenario) -> mujoco.MjSpec:
    """The scenario's world as an uncompiled spec: robot model + floor + arena + objects."""
    spec = (
        _team_spec(scenario)
        if scenario.team
        else mujoco.MjSpec.from_file(str(scenario.robot.spec.path))
    )
    spec.modelname = scenario.name
    spec.option.timestep = scenario.world.timestep
    world = spec.worldbody
    extent = scenario.world.arena.half_size + 1.0 if scenario.world.arena else 5.0
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[extent, extent, 0.1],
        rgba=[0.85, 0.85, 0.8, 1.0],
    )
    world.add_light(
        name="sun", pos=[0, 0, 6], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    )
    if scenario.world.arena:
        _add_arena(world, scenario.world.arena)
    for obj in scenario.world.objects:
        _add_object(world, obj)
    return spec


def compile_model(scenario: Scenario, spec: mujoco.MjSpec | None = None) -> mujoco.MjModel:
    """Compile (a possibly extended copy of) the scenario spec; checks ``robot.qpos`` fits."""
    spec = spec or build_spec(scenario)
    model = spec.compile()
    if scenario.robot.qpos is not None and len(scenario.robot.qpos) > model.nq:
        raise ValueError(
            f"{scenario.source}: robot.qpos has {len(scenario.robot.qpos)} values; "
            f"the {scenario.robot.model} model has nq={model.nq}"
        )
    return model


def reset_data(scenario: Scenario, model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Reset ``data`` to the scenario's initial configuration, kinematics computed.

    ``robot.qpos`` goes into ``data.qpos``, never into ``model.qpos0``: MuJoCo measures hinge and
    slide displacements from qpos0, so writing it there would move the joints' zero instead of the
    robot (a Panda set to its home pose that way is drawn fully stretched).
    """
    mujoco.mj_resetData(model, data)
    for prefix, qpos in [(f"{m.name}/", m.robot.qpos) for m in scenario.team] or [
        ("", scenario.robot.qpos)
    ]:
        if qpos is not None:
            first = next(j for j in range(model.njnt) if model.joint(j).name.startswith(prefix))
            start = model.jnt_qposadr[first]
            data.qpos[start : start + len(qpos)] = qpos
    mujoco.mj_forward(model, data)


def initial_data(scenario: Scenario, model: mujoco.MjModel) -> mujoco.MjData:
    """MjData at the scenario's initial configuration, kinematics computed."""
    data = mujoco.MjData(model)
    reset_data(scenario, model, data)
    return data


def _team_spec(scenario: Scenario) -> mujoco.MjSpec:
    """A team's robots attached under their names (``a/``), in order: their actuators, so the
    world's control vector, follow that order. The options (integrator, ...) are the first
    robot's MJCF's; the robots' MJCFs must agree on them."""
    first = mujoco.MjSpec.from_file(str(scenario.team[0].robot.spec.path))
    spec = mujoco.MjSpec()
    for key in ("timestep", "integrator", "cone", "impratio", "noslip_iterations"):
        setattr(spec.option, key, getattr(first.option, key))
    for m in scenario.team:
        child = mujoco.MjSpec.from_file(str(m.robot.spec.path))
        spec.attach(child, prefix=f"{m.name}/", frame=spec.worldbody.add_frame())
    return spec


def _add_arena(world, arena) -> None:
    """Four walls as planes facing inward at ±half_size.

    Planes, not boxes: a plane's contact and distance queries are analytic, which made
    navigation rollouts 15 % faster and its collision sensors 4x cheaper than with long thin
    boxes (whose bounding spheres always overlap the robot's). ``size`` only bounds the drawing.
    """
    h, z = arena.half_size, arena.wall_height
    r = math.sqrt(0.5)
    # quaternions turn each plane's normal (+z) to point into the arena; the drawn size is
    # (along the wall, up) in the plane's own x, y: the east and west walls' turn about y takes
    # the plane's x upwards, so their sizes swap (else they are drawn 8 m tall, 0.6 m wide)
    for name, pos, quat, size in (
        ("wall_north", [0, h, z], [r, r, 0, 0], [h, z]),
        ("wall_south", [0, -h, z], [r, -r, 0, 0], [h, z]),
        ("wall_east", [h, 0, z], [r, 0, -r, 0], [z, h]),
        ("wall_west", [-h, 0, z], [r, 0, r, 0], [z, h]),
    ):
        body = world.add_body(name=name, pos=pos, quat=quat)
        body.add_geom(
            name=name,
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[*size, 0.1],
            rgba=[0.45, 0.45, 0.5, 1.0],
        )


def _add_object(world, obj: ObjectConfig) -> None:
    yaw = math.radians(obj.yaw)
    quat = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    # Fixed objects are mocap bodies: static for the physics, yet the server can move them
    # (disturbances, randomised starts, scripted obstacles) and their poses travel in the state.
    body = world.add_body(name=obj.name, pos=list(obj.pos), quat=quat, mocap=obj.fixed)
    if not obj.fixed:
        body.add_freejoint(name=f"{obj.name}_free")
    size = list(obj.size) + [0.0] * (3 - len(obj.size))
    geom = body.add_geom(
        name=obj.name,
        type=_GEOM[obj.shape],
        size=size,
        rgba=list(obj.rgba),
        friction=[obj.friction, 0.005, 0.0001],
    )
    if obj.visual:
        geom.contype, geom.conaffinity = 0, 0
        geom.group = 2
    if not obj.fixed:
        geom.mass = obj.mass


# What a world state holds besides time: the fields of the protocol's ``state`` message and of
# the episode log's ``step`` records, in MuJoCo's names.
STATE_FIELDS = ("qpos", "qvel", "act", "mocap_pos", "mocap_quat")


def set_state(model: mujoco.MjModel, data: mujoco.MjData, values: Mapping[str, Any]) -> None:
    """Copy a world state (each of :data:`STATE_FIELDS`, any array shape) into ``data``; sizes
    are checked, a ValueError naming the field. Kinematics are not recomputed: the caller runs
    ``mj_forward`` once it has set what else it needs (time, mocap velocities)."""
    sizes = {
        "qpos": model.nq,
        "qvel": model.nv,
        "act": model.na,
        "mocap_pos": model.nmocap * 3,
        "mocap_quat": model.nmocap * 4,
    }
    for name in STATE_FIELDS:
        value = np.asarray(values[name], dtype=float).reshape(-1)
        if value.size != sizes[name]:
            raise ValueError(f"{name} has {value.size} values, the model needs {sizes[name]}")
        getattr(data, name).flat[:] = value


def contact_friction(
    model: mujoco.MjModel, bodies: Sequence[int]
) -> tuple[np.ndarray, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """The geom priorities ``[ngeom]`` that make the contacts of ``bodies`` (scenario objects)
    theirs, and per body its geoms ``[G]`` with the friction ``[G, 3]`` of their contacts.

    MuJoCo takes the larger of two geoms' frictions at equal priority, so an object's own
    friction (0.5) under the floor's (1.0) decides nothing, and scaling it changes nothing. Here
    the objects' geoms rank above every geom they ranked level with (floor, tables, links) and
    take the larger of their own and those geoms' frictions: they make the same contacts as
    before (exactly when those geoms share one friction), and scaling that friction scales the
    object's contacts (a model's mismatch, its variants). A geom that outranked the objects (a
    gripper's rubber pads, with their own friction, condim and solimp) still does: its contacts
    with an object stay the pad's, whatever the object's factor."""
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    owned = np.isin(model.geom_bodyid, np.asarray(bodies, dtype=int))
    level = int(model.geom_priority[owned].max()) if owned.any() else 0
    priority = model.geom_priority.copy()
    priority[priority > level] += 1
    priority[owned] = level + 1
    out = {}
    for body in bodies:
        own = np.flatnonzero(model.geom_bodyid == body)
        others = collides & (model.geom_bodyid != body) & (model.geom_priority <= level)
        friction = model.geom_friction[own].copy()
        if others.any():
            friction = np.maximum(friction, model.geom_friction[others].max(0))
        out[body] = (own, friction)
    return priority, out
