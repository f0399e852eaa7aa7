"""What MuJoCo Warp (MJWarp) can roll out, checked against the planner's model at start-up.

MJWarp implements most of MuJoCo's pipeline, not all of it: a scenario that needs a geom,
sensor, actuator, equality, solver or option it lacks must stop the planner with a clear error
naming the object, never plan on a silently different model. :func:`warp_limits` lists every
such need (reading MJWarp's own tables of supported types, so the check follows the installed
version), :func:`check_warp` raises them together, and :func:`buffer_sizes` chooses the
per-world contact and constraint capacities.
"""

from __future__ import annotations

from types import ModuleType

import mujoco
import numpy as np

from shared.config import ConfigError

# The state the warp backend copies into each world: mjSTATE_FULLPHYSICS minus what it cannot
# carry (history buffers of delayed actuators/sensors, plastic references, plugin state).
COPIED_STATE = ("TIME", "QPOS", "QVEL", "ACT")
_UNCOPIED_STATE = ("HISTORY", "PLASTIC", "PLUGIN")


def _name(model: mujoco.MjModel, objtype: mujoco.mjtObj, i: int, kind: str) -> str:
    name = mujoco.mj_id2name(model, objtype, i)
    return f"{kind} {name!r}" if name else f"{kind} #{i}"


def warp_limits(model: mujoco.MjModel) -> list[str]:
    """Every feature of ``model`` MJWarp cannot simulate, one line each naming the object
    (``geom 'shelf' has type mjGEOM_SKIN``); empty when it can roll out the model.

    Needs the ``m3p2i[gpu]`` extra (mujoco-warp); compiles no kernels.
    """
    # mujoco_warp exports only some of its enums at the top level; these are its tables of
    # supported MuJoCo values (put_model checks against the same ones)
    from mujoco_warp._src import types as T

    return [
        *_unsupported_types(model, T),
        *_unsupported_wraps(model, T),
        *_unsupported_options(model, T),
        *_unsupported_flags(model, T),
        *_plugins(model),
        *_dense_jacobian(model),
        *_adhesion_with_distance_sensors(model),
        *_uncopied_state(model),
    ]


def _unsupported_types(model: mujoco.MjModel, T: ModuleType) -> list[str]:
    """Geoms, sensors, actuators (transmission, dynamics, gain, bias) and equalities of a type
    outside MJWarp's table ``T`` of that type."""
    Obj = mujoco.mjtObj
    problems: list[str] = []
    per_object = (
        (model.geom_type, T.GeomType, mujoco.mjtGeom, Obj.mjOBJ_GEOM, "geom", "type"),
        (model.sensor_type, T.SensorType, mujoco.mjtSensor, Obj.mjOBJ_SENSOR, "sensor", "type"),
        (
            model.actuator_trntype,
            T.TrnType,
            mujoco.mjtTrn,
            Obj.mjOBJ_ACTUATOR,
            "actuator",
            "transmission",
        ),
        (
            model.actuator_dyntype,
            T.DynType,
            mujoco.mjtDyn,
            Obj.mjOBJ_ACTUATOR,
            "actuator",
            "dynamics",
        ),
        (
            model.actuator_gaintype,
            T.GainType,
            mujoco.mjtGain,
            Obj.mjOBJ_ACTUATOR,
            "actuator",
            "gain",
        ),
        (
            model.actuator_biastype,
            T.BiasType,
            mujoco.mjtBias,
            Obj.mjOBJ_ACTUATOR,
            "actuator",
            "bias",
        ),
        (model.eq_type, T.EqType, mujoco.mjtEq, Obj.mjOBJ_EQUALITY, "equality", "type"),
    )
    for values, supported, enum, objtype, kind, what in per_object:
        ok = {int(v) for v in supported}
        for i, v in enumerate(np.asarray(values).ravel()):
            if int(v) not in ok:
                problems.append(f"{_name(model, objtype, i, kind)} has {what} {enum(int(v)).name}")
    return problems


def _unsupported_wraps(model: mujoco.MjModel, T: ModuleType) -> list[str]:
    """Tendon wraps of a type MJWarp lacks (wraps have no names: by index)."""
    ok_wrap = {int(v) for v in T.WrapType}
    return [
        f"tendon wrap #{i} has type {mujoco.mjtWrap(int(v)).name}"
        for i, v in enumerate(model.wrap_type)
        if int(v) not in ok_wrap
    ]


def _unsupported_options(model: mujoco.MjModel, T: ModuleType) -> list[str]:
    """An integrator, friction cone or solver MJWarp lacks."""
    problems = []
    for value, supported, enum, what in (
        (model.opt.integrator, T.IntegratorType, mujoco.mjtIntegrator, "integrator"),
        (model.opt.cone, T.ConeType, mujoco.mjtCone, "cone"),
        (model.opt.solver, T.SolverType, mujoco.mjtSolver, "solver"),
    ):
        if int(value) not in {int(v) for v in supported}:
            problems.append(f"option {what} {enum(int(value)).name}")
    return problems


def _unsupported_flags(model: mujoco.MjModel, T: ModuleType) -> list[str]:
    """Each disable or enable flag set in the model that MJWarp's flag tables lack."""
    problems = []
    for flags, supported, enum, what in (
        (model.opt.disableflags, T.DisableBit, mujoco.mjtDisableBit, "disable flag"),
        (model.opt.enableflags, T.EnableBit, mujoco.mjtEnableBit, "enable flag"),
    ):
        known = int(np.bitwise_or.reduce([int(v) for v in supported]))
        bit = 1
        while bit <= int(flags):
            if int(flags) & bit and not bit & known:
                problems.append(f"option {what} {enum(bit).name}")
            bit <<= 1
    return problems


def _plugins(model: mujoco.MjModel) -> list[str]:
    """Bodies, actuators and sensors that use an engine plugin (MJWarp runs none)."""
    Obj = mujoco.mjtObj
    problems = []
    for values, objtype, kind in (
        (model.body_plugin, Obj.mjOBJ_BODY, "body"),
        (model.actuator_plugin, Obj.mjOBJ_ACTUATOR, "actuator"),
        (model.sensor_plugin, Obj.mjOBJ_SENSOR, "sensor"),
    ):
        for i in np.flatnonzero(np.asarray(values) != -1):
            problems.append(f"{_name(model, objtype, int(i), kind)} uses a plugin")
    return problems


def _dense_jacobian(model: mujoco.MjModel) -> list[str]:
    """A dense constraint Jacobian past the size MJWarp computes densely."""
    if model.nv > 60 and model.opt.jacobian == mujoco.mjtJacobian.mjJAC_DENSE:
        return [
            f"option jacobian mjJAC_DENSE with nv = {model.nv} (MJWarp: dense only "
            "up to nv = 60; use sparse or auto)"
        ]
    return []


def _uncopied_state(model: mujoco.MjModel) -> list[str]:
    """State the warp backend cannot copy into its worlds (:data:`_UNCOPIED_STATE`): a
    rollout would start without it."""
    problems = []
    for part in _UNCOPIED_STATE:
        n = mujoco.mj_stateSize(model, getattr(mujoco.mjtState, f"mjSTATE_{part}"))
        if n:
            problems.append(
                f"{n} values of {part.lower()} state (the warp backend starts each "
                f"rollout from {', '.join(p.lower() for p in COPIED_STATE)} only)"
            )
    return problems


def _adhesion_with_distance_sensors(model: mujoco.MjModel) -> list[str]:
    """Adhesion (body-transmission) actuators on a body that a distance sensor also measures.

    MJWarp 4.0.0 adds the geom pairs of GEOMDIST/GEOMNORMAL/GEOMFROMTO sensors to its contact
    buffer as distance-only entries, and its body transmission averages the adhesion force over
    every contact of the body, those included. Measured on push_pull (the suction actuator on the
    robot, four robot-wall distance sensors): 16 such entries beside the 2 real robot-box
    contacts, so the box felt 11 N of the actuator's 100 N (MuJoCo: 100 N), and rollouts with
    suction on drifted up to 0.35 m from mujoco.rollout's within 0.75 s. The same model without
    the distance sensors agrees within 5e-3 m with the suction on (measured 2026-11-30), which
    locates the difference there.
    """
    Obj, S = mujoco.mjtObj, mujoco.mjtSensor
    dist_types = {int(S.mjSENS_GEOMDIST), int(S.mjSENS_GEOMNORMAL), int(S.mjSENS_GEOMFROMTO)}

    def bodies(objtype: int, objid: int) -> set[int]:
        if objtype == int(Obj.mjOBJ_BODY):
            return {objid}
        if objtype == int(Obj.mjOBJ_GEOM):
            return {int(model.geom_bodyid[objid])}
        return set()

    problems = []
    for a in np.flatnonzero(model.actuator_trntype == int(mujoco.mjtTrn.mjTRN_BODY)):
        body = int(model.actuator_trnid[a, 0])
        sensors = [
            _name(model, Obj.mjOBJ_SENSOR, int(s), "sensor")
            for s in range(model.nsensor)
            if int(model.sensor_type[s]) in dist_types
            and body
            in bodies(int(model.sensor_objtype[s]), int(model.sensor_objid[s]))
            | bodies(int(model.sensor_reftype[s]), int(model.sensor_refid[s]))
        ]
        if sensors:
            problems.append(
                f"{_name(model, Obj.mjOBJ_ACTUATOR, int(a), 'actuator')} (adhesion on body "
                f"{model.body(body).name!r}) with distance sensors of that body "
                f"({', '.join(sensors)}): MJWarp counts the sensors' distance-only contacts in "
                "the adhesion's average and weakens it (measured on push_pull: 11 N instead of "
                "100 N)"
            )
    return problems


def check_warp(model: mujoco.MjModel, source: str = "") -> None:
    """Raise :class:`ConfigError` (key ``planner.backend`` of scenario file ``source``) naming
    every feature of ``model`` MJWarp cannot roll out."""
    problems = warp_limits(model)
    if problems:
        raise ConfigError(
            source,
            "planner.backend",
            "MuJoCo Warp cannot roll out this scenario's model: " + "; ".join(problems),
            "warp",
            "planner.backend: mujoco, or a model within MJWarp's limits",
        )


def buffer_sizes(
    model: mujoco.MjModel, nconmax: int | None = None, njmax: int | None = None
) -> tuple[int, int]:
    """Contacts and constraint rows allocated per world: the given ones, else twice what
    MuJoCo finds at the model's reference pose or MJWarp's own default, whichever is larger.

    MJWarp allocates these buffers once; rollouts that need more overflow, and the backend
    reports it (those samples get no weight) rather than returning a truncated contact set.
    """
    from mujoco_warp._src import io

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # twice the reference pose's count: rollouts touch and grasp more than the start pose does
    if nconmax is None:
        nconmax = max(io._default_nconmax(model), 2 * data.ncon)
    if njmax is None:
        njmax = max(io._default_njmax(model), 2 * data.nefc)
    return int(nconmax), int(njmax)
