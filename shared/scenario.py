"""Scenario files: one YAML per scenario (found as :mod:`shared.config_files` says), parsed into
typed dataclasses and validated once, at load. Both processes load the same file; its hash is
checked in the handshake so that they can never silently plan for different worlds.

The schema, key by key, is documented in ``docs/scenarios.md``.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.config import (
    ConfigError,
    ErrorLog,
    Section,
    deprecated,
    flag,
    load_yaml,
    non_negative,
    number,
    one_of,
    positive,
    positive_int,
    string_list,
    vector,
)
from shared.config_files import find, shipped
from shared.faults import NOMINAL, OLD_NAME, FaultConfig, parse_faults, read_old_name
from shared.geometry import AXES
from shared.guide import GuideConfig, parse_guide
from shared.predicates import Predicate, parse_predicate
from shared.robots import ROBOT_KEYS, ROBOTS, RobotSpec, get_robot, load_robot, parse_robot
from shared.task_template import FactorTemplate, TaskTemplate, parse_task

SCENARIO_DIR = shipped("scenarios")  # the scenarios shipped with m3p2i

SHAPES = ("box", "cylinder", "sphere")
_SIZE_LEN = {"box": 3, "cylinder": 2, "sphere": 1}


@dataclass(frozen=True)
class RobotConfig:
    """``robot:``: the robot (its name, and what its robot file says) and its start."""

    model: str  # the robot's name: a robot file's stem, or the MJCF's for a robot declared inline
    qpos: tuple[float, ...] | None = None  # initial joint positions; None = the model's default
    # what the robot file says (frame, controls, safe control); by default, get_robot(model)
    spec: RobotSpec = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.spec is None:
            object.__setattr__(self, "spec", get_robot(self.model))


@dataclass(frozen=True)
class ObjectConfig:
    """A body added to the world. ``size`` uses MuJoCo's half-size convention per shape."""

    name: str
    shape: str
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    yaw: float = 0.0  # degrees about z
    fixed: bool = True  # False: a free body that can be pushed
    mass: float = 1.0
    friction: float = 0.5
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)
    visual: bool = False  # a marker: drawn, never collides
    obstacle: bool = True  # counted by collision cost terms (non-visual only)


@dataclass(frozen=True)
class ArenaConfig:
    """Walls of a square arena at ±half_size around the origin (thesis code: 4 m); drawn
    ``wall_height`` high."""

    half_size: float = 4.0
    wall_height: float = 0.3


@dataclass(frozen=True)
class BatteryConfig:
    """Simulated battery (thesis Eq. 4.1): +rate %/s within ``radius`` of ``charger``, else
    -rate %/s, bounded to [0, 100]; published as the state extra ``battery``."""

    charger: str
    rate: float
    radius: float = 0.5
    initial: float = 100.0


@dataclass(frozen=True)
class RandomizeConfig:
    """An object's start pose, drawn per episode from the server's --seed: uniform ranges for
    ``x``, ``y`` and ``yaw``, or ``choose``: one of a few start positions [x, y, z], each equally
    likely (discrete cases of one scenario, e.g. a cube on the table or on a shelf)."""

    object: str
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    yaw: tuple[float, float] | None = None  # degrees
    choose: tuple[tuple[float, float, float], ...] | None = None


@dataclass(frozen=True)
class MoveConfig:
    """Teleport ``object`` to ``pos``/``yaw`` (None keeps that part) once: at time ``at``, or at
    the first step from ``at`` on where ``when`` holds (e.g. stealing a cube from the hand), or
    ``delay`` seconds after that step (a person who takes an obstacle away a moment later)."""

    object: str
    at: float = 0.0
    when: Predicate | None = None
    pos: tuple[float, float, float] | None = None
    yaw: float | None = None
    delay: float = 0.0


@dataclass(frozen=True)
class PathConfig:
    """Move a fixed (mocap) ``object`` through ``waypoints`` at ``speed`` m/s from time ``start``;
    ``loop`` returns to the first waypoint and repeats (a dynamic obstacle)."""

    object: str
    waypoints: tuple[tuple[float, float, float], ...]
    speed: float
    start: float = 0.0
    loop: bool = True


@dataclass(frozen=True)
class WorldConfig:
    timestep: float
    objects: tuple[ObjectConfig, ...] = ()
    arena: ArenaConfig | None = None
    battery: BatteryConfig | None = None
    randomize: tuple[RandomizeConfig, ...] = ()
    disturbances: tuple[MoveConfig | PathConfig, ...] = ()


@dataclass(frozen=True)
class ObserverConfig:
    """Symbolic observer of one task factor: the first rule whose predicate holds gives the
    observed state; ``default`` when none holds."""

    rules: tuple[tuple[str, Predicate], ...]
    default: str


@dataclass(frozen=True)
class EpisodeConfig:
    max_time: float
    success: tuple[Predicate, ...]
    hold: float = 0.0  # seconds the success predicates must hold without a break


@dataclass(frozen=True)
class FramePairConfig:
    """Two frames an evaluation metric compares; for positions, ``b`` shifted by ``offset``
    (world frame, m; e.g. on top of a cube) and only the ``axes`` components."""

    a: str
    b: str
    axes: str = "xyz"
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CollisionMetricConfig:
    """Count contact onsets between the bodies of ``a`` and the bodies ``with_`` (``robot``: the
    whole robot; any other name: that body and the bodies it carries)."""

    a: tuple[str, ...]
    with_: tuple[str, ...]


@dataclass(frozen=True)
class MetricsConfig:
    """What ``shared.evaluation.metrics`` measures per episode (``metrics:``; docs/evaluation.md). A
    metric left as None is not measured."""

    position: FramePairConfig | None = None
    orientation: FramePairConfig | None = None
    collisions: CollisionMetricConfig | None = None


@dataclass(frozen=True)
class TermConfig:
    """One cost term of an objective as written in YAML; the planner validates ``params``."""

    term: str
    weight: float
    params: dict[str, Any]
    path: str  # key path, for the planner's error messages
    source: str = ""  # the file it is written in, when not the scenario's


@dataclass(frozen=True)
class ObjectiveConfig:
    terms: tuple[TermConfig, ...]
    fixed: dict[str, float] = field(default_factory=dict)  # actuator name -> pinned control


# Rollout backends (planner.backend): "mujoco" is mujoco.rollout's thread pool on the CPU, the
# default; "warp" is MuJoCo Warp (the m3p2i[gpu] extra) on planner.device.
ROLLOUT_BACKENDS = ("mujoco", "warp")


def rollout_device(value: Any) -> str:
    """Converter for a warp device name: ``cpu``, ``cuda`` or ``cuda:N``."""
    if not isinstance(value, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", value):
        raise ValueError("must be cpu, cuda or cuda:N")
    return value


VARIANT_PARAMS = ("mass", "friction", "gain")
VARIANT_AGGREGATES = ("mean", "cvar", "worst")
VARIANT_SPREADS = ("split", "all", "estimate")


@dataclass(frozen=True)
class IdentifyConfig:
    """``planner.model.variants.identify``: the variants reweighted by how well each predicted
    the last observed transition (planner_client.variants; docs/scenarios.md, "Model variants").
    ``position_sigma`` and ``velocity_sigma``: the spread of a prediction's error that a right
    model still makes (measurement noise, the mirror's estimates), for the free objects'
    positions and the robot's velocities; ``forget``: the share of the past evidence each new
    transition keeps (old evidence fades, so the ensemble widens again when the world changes);
    ``floor``: the share of the variants redrawn from the prior at each resampling;
    ``jitter``: each kept variant's factors moved by this fraction of the prior's half-width;
    ``window``: the world steps each prediction spans (1: from the previous state received;
    more: from the state ``window`` steps back, its objects' positions and velocities a line
    fitted through the poses received around it)."""

    position_sigma: float = 0.005
    velocity_sigma: float = 0.02
    forget: float = 0.9
    floor: float = 0.1
    jitter: float = 0.1
    window: int = 1

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class VariantsConfig:
    """``planner.model.variants``: ``count`` copies of the planner's model whose parameters are
    scaled by factors drawn (from ``seed``) uniformly in ``[1 - f, 1 + f]``, per scenario object
    for ``mass`` (masses and inertias) and ``friction`` (its contacts' friction), per actuator
    for ``gain`` (gain and bias). ``spread: split``: sample ``k`` rolls out in variant
    ``k mod count`` (no extra rollouts); ``all``: every sample in every variant, its cost the
    ``aggregate`` over them (``mean``, ``cvar``: the mean of the worst ``cvar_alpha`` share,
    ``worst``); ``estimate``: every sample in one model at the identified factors (the
    variants only identify; needs ``identify``). ``identify``: the variants reweighted and
    resampled online."""

    count: int = 8
    seed: int = 0
    mass: float = 0.0
    friction: float = 0.0
    gain: float = 0.0
    spread: str = "split"
    aggregate: str = "mean"
    cvar_alpha: float = 0.25
    identify: IdentifyConfig | None = None

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k not in VARIANT_PARAMS + ("identify",)}
        out["params"] = {k: getattr(self, k) for k in VARIANT_PARAMS if getattr(self, k)}
        if self.identify is not None:
            out["identify"] = self.identify.as_dict()
        return out


@dataclass(frozen=True)
class PlanningModel:
    """``planner.model``: options of the planner's own copy of the model (its rollouts), never
    the world's; None keeps the world model's value. A planner may roll out a cheaper model
    than the world simulates, as long as its plans still work on the world."""

    solver: str | None = None  # Newton | CG | PGS
    iterations: int | None = None  # constraint solver iterations
    ls_iterations: int | None = None  # line-search iterations (Newton, CG)
    tolerance: float | None = None  # solver tolerance; 0 disables early termination
    cone: str | None = None  # pyramidal | elliptic friction cones
    noslip_iterations: int | None = None  # 0 disables the no-slip solver
    integrator: str | None = None  # Euler | implicitfast | implicit | RK4
    condim: int | None = None  # every geom's contact dimensionality (1, 3, 4, 6)
    exclude: tuple[tuple[str, str], ...] = ()  # body pairs whose contacts the rollouts skip
    attach: tuple[Attach, ...] = ()  # objects welded to the robot while a task state holds
    objects: dict[str, ObjectModel] = field(default_factory=dict)  # per free object, by name
    geoms: dict[str, GeomModel] = field(default_factory=dict)  # collision shapes, by geom name
    variants: VariantsConfig | None = None  # rollouts over V drawn models (planner_client.variants)

    def as_dict(self) -> dict[str, Any]:
        """The keys set, as written in YAML (for logs and benchmark rows)."""
        out = {
            k: v
            for k, v in self.__dict__.items()
            if v is not None and k not in ("exclude", "attach", "objects", "geoms", "variants")
        }
        if self.exclude:
            out["exclude"] = [list(pair) for pair in self.exclude]
        if self.attach:
            out["attach"] = [
                {"object": a.object, "to": a.to, "while": a.state} for a in self.attach
            ]
        if self.objects:
            out["objects"] = {name: o.as_dict() for name, o in self.objects.items()}
        if self.geoms:
            out["geoms"] = {name: g.as_dict() for name, g in self.geoms.items()}
        if self.variants is not None:
            out["variants"] = self.variants.as_dict()
        return out


GEOM_TYPES = ("sphere", "capsule", "cylinder", "box", "ellipsoid")


@dataclass(frozen=True)
class GeomModel:
    """``planner.model.geoms.<name>``: another collision shape for one geom (of the robot or of
    an object) in the planner's model: a sphere or a box collides with a box analytically, a
    cylinder through the general convex solver at several times the cost. Unset keys keep the
    geom's own; ``pos`` is in its body's frame."""

    type: str | None = None
    size: tuple[float, ...] | None = None
    pos: tuple[float, float, float] | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in self.__dict__.items()
            if v is not None
        }


# The six degrees of freedom of a free object's joint, in MuJoCo's order: translations along the
# world's x, y, z, then rotations about the object's own x, y, z axes (for an object lying flat:
# roll, pitch, yaw).
FREE_DOFS = ("x", "y", "z", "rx", "ry", "rz")


@dataclass(frozen=True)
class ObjectModel:
    """``planner.model.objects.<name>``: the planner's own physics of one free object. An object
    that rests on the floor can be excluded from it (``exclude: [[world, name]]``), its weight
    compensated (``gravcomp: 1``) and the floor's friction replaced by resistance on its joint
    (``frictionloss``: dry, ``damping``: viscous): a few passive terms instead of a contact each
    step. Per-DOF values are six numbers in :data:`FREE_DOFS` order, or one for all six."""

    gravcomp: float | None = None  # 1: the object's weight is cancelled
    damping: tuple[float, ...] | None = None  # N·s/m, N·m·s/rad per DOF
    frictionloss: tuple[float, ...] | None = None  # N, N·m per DOF (dry friction)
    armature: tuple[float, ...] | None = None  # kg, kg·m² added per DOF
    # lying flat: each received state is put into the rollouts at the object's start height,
    # turned about z only, with no z, roll or pitch velocity (planner_client.mirror)
    planar: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in self.__dict__.items()
            if v is not None
        }


@dataclass(frozen=True)
class Attach:
    """``planner.model.attach[i]``: while the task observes ``state`` (e.g. ``holding``), the
    planner's model welds ``object`` to robot body ``to`` at their pose of the moment and drops
    the object's contacts with the robot (planner_client.attach). A grasp's pad contacts are
    most of a carrying rollout's cost; the world keeps them."""

    object: str  # a free object of the scenario
    to: str  # a body of the robot (e.g. its hand)
    state: str  # a state of a task factor (YAML key ``while``)


@dataclass(frozen=True)
class EstimateConfig:
    """``planner.estimate``: how the planner's mirror turns received states of the free bodies
    (the scenario's objects) into the rollouts' start, for worlds whose object poses come from
    perception (noisy) and whose object velocities are not measured."""

    object_velocities: str = "received"  # received | from_poses (finite differences)
    pose_filter: float = 1.0  # weight of a new pose in an exponential filter; 1: none
    velocity_filter: float = 1.0  # weight of a new finite-difference velocity; 1: none
    max_speed: float = 5.0  # m/s: a faster jump is a teleport (filters restart)
    held_filter: float = 1.0  # weight of a new relative pose of an attached object
    still_speed: float = 0.0  # m/s: a slower filtered velocity is noise, taken as 0
    predict: bool = False  # blend a new pose with the last one moved on by its velocity


@dataclass(frozen=True)
class DelayConfig:
    """``planner.delays``: delays of the robot that no message shows, declared so the planner
    plans for the state its plan will meet (docs/faults.md, "Delay compensation").
    ``actuation_ms``: from a command reaching the world to the actuators acting on it;
    ``state_ms``: from a measurement to its state being published (a state's ``time`` is
    its measurement's). ``estimate``: measure them online instead, the state delay from
    ``state.lag``, the actuation delay (up to ``max_ms``) from the robot's response; a declared
    value stands until the estimate has one."""

    actuation_ms: float = 0.0
    state_ms: float = 0.0
    estimate: bool = False  # measure both online (planner_client/delay_estimate.py)
    max_ms: float = 300.0  # the longest actuation delay the estimate considers

    @property
    def active(self) -> bool:
        return bool(self.actuation_ms or self.state_ms or self.estimate)


SOLVERS = ("Newton", "CG", "PGS")
CONES = ("pyramidal", "elliptic")
INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")


@dataclass(frozen=True)
class PlannerConfig:
    """Motion-planner parameters; ``mppi`` keys are checked by the planner against MPPIConfig."""

    samples: int = 200
    horizon: int = 15
    mppi: dict[str, Any] = field(default_factory=dict)
    threads: int = 0  # rollout threads; 0 = one per core
    aip_period: float = 0.2  # simulated seconds between active-inference ticks
    # seconds an observed change of a task factor must persist before the task layer acts on
    # it, per factor ("*": the others); 0 acts on every observation (planner_client.task)
    confirm: dict[str, float | dict[str, float]] = field(default_factory=dict)
    timestep: float | None = None  # planning step (s), a multiple of the world's; None = its
    backend: str = "mujoco"  # rollouts: "mujoco" (mujoco.rollout pool) or "warp" (MJWarp)
    device: str = "cuda:0"  # the warp backend's device: "cpu" or "cuda[:N]"
    nconmax: int | None = None  # warp: contacts per world; None = estimated at start
    njmax: int | None = None  # warp: constraint rows per world; None = estimated
    model: PlanningModel = PlanningModel()  # the rollout model's own options
    estimate: EstimateConfig = EstimateConfig()  # the mirror's filters for the free bodies
    delays: DelayConfig = DelayConfig()  # the robot's unseen delays, compensated by prediction

    def step(self, world: WorldConfig) -> float:
        """Seconds per planned control step: ``timestep``, or the world's."""
        return self.timestep or world.timestep


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    hash: str
    robot: RobotConfig
    world: WorldConfig
    episode: EpisodeConfig
    planner: PlannerConfig
    objectives: dict[str, ObjectiveConfig]
    modes: tuple[str, ...]  # fixed modes (when there is no task template)
    task: TaskTemplate | None = None
    observers: dict[str, ObserverConfig] = field(default_factory=dict)
    # the plan interface, YAML key ``plan``: task action -> the objective that executes it
    action_objectives: dict[str, str] = field(default_factory=dict)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    # the world server's simulated faults (docs/faults.md); the planner keeps the nominal model
    faults: FaultConfig = NOMINAL
    # the user's modules of cost terms and observer predicates, imported by the planner
    # (planner_client.plugins): NAME.py beside the scenario, else a module name; never the world
    plugins: tuple[str, ...] = ()
    raw: dict = field(repr=False, default_factory=dict)
    guide: GuideConfig | None = None  # a global path the planner's terms follow (shared/guide.py)


def find_scenario(name_or_path: str | os.PathLike) -> Path:
    """A path as given, else ``NAME.yaml`` in the user's scenario folders, then the shipped ones."""
    return find(name_or_path, "scenarios")


def load_scenario(name_or_path: str | os.PathLike) -> Scenario:
    """Load and validate a scenario; raises :class:`ConfigError` naming file, key, value (or
    :class:`~shared.config.ConfigErrors` with every error of the file)."""
    reading = read_scenario(name_or_path)
    reading.raise_if_any()
    return reading.scenario


@dataclass
class ScenarioReading:
    """A scenario file read with every error collected instead of raised at the first.

    ``scenario`` is what could be read (None when not even a robot could be read: no file,
    bad YAML, an unknown robot); faulty parts are left out of it, so it serves only checks.
    ``model_ok``: the robot and the world were read without error, so the compiled model is
    the one the file describes and model checks (frames, actuators, sensors) mean something.
    Without it, the scenario's world is a stand-in of the names the file declares (its objects,
    the arena's walls): enough to check the names the file uses, against them and the robot's
    bodies and sites (:mod:`shared.scenario_check`).
    """

    scenario: Scenario | None
    errors: list[ConfigError]
    model_ok: bool

    def raise_if_any(self) -> None:
        log = ErrorLog()
        log.errors = list(self.errors)
        log.raise_if_any()


def read_scenario(name_or_path: str | os.PathLike) -> ScenarioReading:
    """Read a scenario, collecting every load-time error (see :class:`ScenarioReading`)."""
    errors = ErrorLog()
    path = errors.call(find_scenario, name_or_path)
    raw = errors.call(load_yaml, path) if path is not None else None
    if raw is not None:
        raw = errors.call(with_base, raw, str(path))
    if raw is None:
        return ScenarioReading(None, errors.errors, False)
    return _read(raw, str(path), errors)


def with_base(raw: Any, source: str, _seen: tuple[Path, ...] = ()) -> Any:
    """``base: NAME or path`` (a path relative to ``source``'s folder first): the scenario
    ``raw`` over the one it names, mappings merged key by key; a list or a value replaces the
    base's, ``null`` removes the key. ``name`` is not inherited (default: the file's stem). A
    base may have its own base. Raises :class:`ConfigError` naming the file and the base.
    Every file's ``hardware:``, the old name of ``faults:``, is read as ``faults:`` first."""
    raw = read_old_name(raw, source)
    if not isinstance(raw, dict) or "base" not in raw:
        return raw
    spec = raw["base"]
    if not isinstance(spec, str) or not spec:
        raise ConfigError(
            source, "base", "not a scenario name or path", spec, "e.g. base: pick_place"
        )
    me = Path(source).resolve()
    near = [Path(source).parent / spec, Path(source).parent / f"{spec}.yaml"]
    try:
        path = next((p for p in near if p.is_file()), None) or find_scenario(spec)
        path = path.resolve()
    except ConfigError:
        raise ConfigError(
            source, "base", "no such scenario", spec, "a scenario name (m3p2i list) or a YAML path"
        ) from None
    if path == me and (shipped("scenarios") / f"{spec}.yaml").is_file():
        path = (
            shipped("scenarios") / f"{spec}.yaml"
        ).resolve()  # a user's file over the shipped one
    if path in _seen or path == me:
        raise ConfigError(
            source,
            "base",
            "a scenario cannot be its own base",
            spec,
            "a chain of bases without a loop",
        )
    base = with_base(load_yaml(path), str(path), _seen + (me,))
    if not isinstance(base, dict):
        raise ConfigError(
            str(path),
            "",
            "a scenario must be a mapping",
            type(base).__name__,
            "keys such as name, robot, world",
        )
    merged = _merge(base, {k: v for k, v in raw.items() if k != "base"})
    if "name" not in raw:
        merged.pop("name", None)
    return merged


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def find_objectives(name_or_path: str | os.PathLike) -> Path:
    """A path as given, else ``NAME.yaml`` in the user's objectives folders, then the shipped
    ones."""
    return find(name_or_path, "objectives")


def scenario_hash(
    raw: dict, included: Sequence[dict] = (), robot: RobotSpec | None = None, source: str = ""
) -> str:
    """Hash of the scenario's content, of the objective files it includes, of its robot's MJCF
    file and of a robot file of the user's (the shipped ones are part of the package, and a
    shipped scenario keeps the hash it had before robots were files). ``faults:`` is hashed under
    its old name, ``hardware:``: a scenario keeps its hash (bench results, logs, an older peer's)
    whichever name it uses."""
    if "faults" in raw:
        raw = {(OLD_NAME if k == "faults" else k): v for k, v in raw.items()}
    h = hashlib.sha256(json.dumps(raw, sort_keys=True, default=str).encode())
    for inc in included:
        h.update(json.dumps(inc, sort_keys=True, default=str).encode())
    if robot is not None:
        h.update(robot.path.read_bytes())
        if robot.source and robot.source != source and not robot.shipped:
            h.update(Path(robot.source).read_bytes())
    return h.hexdigest()[:16]


def parse_scenario(raw: dict, source: str) -> Scenario:
    """A scenario from its YAML mapping; raises with every error of the file."""
    reading = _read(with_base(raw, source), source, ErrorLog())
    reading.raise_if_any()
    return reading.scenario


def _read(raw: dict, source: str, errors: ErrorLog) -> ScenarioReading:
    """Each independent part is read under ``errors``: a fault is recorded and the part left
    out, and the rest is still read. Parts that depend on a faulty one (observers on the task,
    metrics on the episode) are skipped rather than reported again."""
    n_before = len(errors.errors)
    top = Section(raw, source)
    name = errors.call(top.req, "name", str, default=Path(source).stem)
    description = errors.call(top.opt, "description", "", str, default="")
    robot = errors.call(lambda: _robot(top.section("robot")))
    world = errors.call(lambda: _world(top.section("world"), errors))
    model_ok = len(errors.errors) == n_before
    episode = errors.call(lambda: _episode(top.section("episode"), errors))
    metrics = MetricsConfig()
    if episode is not None:
        metrics = errors.call(
            lambda: _metrics(top.section("metrics", required=False), episode), default=metrics
        )
    else:
        top.section("metrics", required=False)
    planner = errors.call(
        lambda: _planner(top.section("planner", required=False)), default=PlannerConfig()
    )
    if world is not None and planner.timestep is not None:
        ratio = planner.timestep / world.timestep
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            errors.add(
                ConfigError(
                    source,
                    "planner.timestep",
                    "not a whole multiple of world.timestep",
                    planner.timestep,
                    f"{world.timestep} × 1, 2, 3, ... seconds",
                )
            )
    faults = NOMINAL
    if top.has("faults"):  # a profile's name or a mapping
        faults = errors.call(parse_faults, top.opt("faults", None), source, default=NOMINAL)
    plugins = errors.call(
        top.opt,
        "plugins",
        (),
        string_list,
        "a list of Python modules: NAME.py beside the scenario, or importable module names",
        default=(),
    )
    library, included = _includes(top, errors)
    objectives = errors.call(
        lambda: _objectives(top.section("objectives"), errors, library), default={}
    )
    task = errors.call(lambda: parse_task(top.section("task"))) if top.has("task") else None
    observers, action_objectives, modes = {}, {}, ()
    if task is None and not top.has("task"):
        modes = errors.call(
            top.req,
            "modes",
            string_list,
            "a list of objective names (or a task: template)",
            default=(),
        )
    else:
        modes = errors.call(
            top.opt, "modes", (), string_list, "a list of objective names", default=()
        )
        if task is not None:
            observers = errors.call(
                lambda: _observers(top.section("observers"), task, errors, bool(plugins)),
                default={},
            )
            action_objectives = errors.call(
                lambda: _action_objectives(top.section("plan"), task, objectives), default={}
            )
        else:  # the task's own errors are reported; its dependants would only repeat them
            top.section("observers", required=False)
            top.section("plan", required=False)
    if planner is not None and planner.confirm and task is None and not top.has("task"):
        errors.add(
            ConfigError(
                source,
                "planner.confirm",
                "only a task's observers are confirmed",
                raw["planner"]["confirm"],
                "a scenario with a task: template",
            )
        )
    elif planner is not None and task is not None:
        factors = [f.name for f in task.factors]
        for key, hold in planner.confirm.items():
            if key != "*" and key not in factors:
                errors.add(
                    ConfigError(
                        source,
                        f"planner.confirm.{key}",
                        "not a factor of the task",
                        key,
                        "'*' or one of: " + ", ".join(factors),
                    )
                )
            elif isinstance(hold, dict):
                states = next(f.states for f in task.factors if f.name == key)
                for state in hold:
                    if state not in states:
                        errors.add(
                            ConfigError(
                                source,
                                f"planner.confirm.{key}.{state}",
                                "not a state of the factor",
                                state,
                                "one of: " + ", ".join(states),
                            )
                        )
    if planner is not None and planner.model.objects and world is not None:
        free = [o.name for o in world.objects if not o.fixed]
        for obj in planner.model.objects:
            if obj not in free:
                errors.add(
                    ConfigError(
                        source,
                        f"planner.model.objects.{obj}",
                        "not a free object of the world",
                        obj,
                        "one of: " + (", ".join(free) or "(none)"),
                    )
                )
    if planner is not None and planner.model.attach:
        _check_attach(planner, task, world, source, errors)
    elif planner is not None and planner.estimate.held_filter < 1.0:
        errors.add(
            ConfigError(
                source,
                "planner.estimate.held_filter",
                "filters the pose of an attached object, and nothing is attached",
                planner.estimate.held_filter,
                "planner.model.attach, or no held_filter",
            )
        )
    if top.has("objectives") and isinstance(top.data["objectives"], dict):
        known = list(top.data["objectives"])
        for i, m in enumerate(modes):
            if m not in known:
                errors.add(
                    ConfigError(
                        source,
                        f"modes[{i}]",
                        "not an objective of this scenario",
                        m,
                        f"one of: {', '.join(known)}",
                    )
                )
    guide = None
    if top.has("guide") and world is not None:
        guide = errors.call(
            lambda: parse_guide(
                top.section("guide"), {o.name: not o.fixed for o in world.objects if not o.visual}
            )
        )
    elif top.has("guide"):  # the world's own errors are reported; the guide's would repeat them
        top.section("guide", required=False)
    if guide is not None and planner is not None and planner.backend != "mujoco":
        errors.add(
            ConfigError(
                source,
                "guide",
                "moves its sub-goal in the planner's model between iterations, which the "
                "warp backend copies once",
                planner.backend,
                "planner.backend: mujoco, or no guide",
            )
        )
    errors.call(top.done)
    if robot is None:
        return ScenarioReading(None, errors.errors, False)
    if world is None:  # what the faulty world declares stands in, for name checks only
        world = _declared_world(raw.get("world"), source)
    scenario = Scenario(
        name=name,
        description=description,
        source=source,
        hash=scenario_hash(raw, included, robot.spec, source),
        robot=robot,
        world=world,
        episode=episode or EpisodeConfig(max_time=0.0, success=()),
        planner=planner,
        objectives=objectives,
        modes=modes,
        task=task,
        observers=observers,
        action_objectives=action_objectives,
        metrics=metrics,
        faults=faults,
        plugins=plugins,
        raw=raw,
        guide=guide,
    )
    return ScenarioReading(scenario, errors.errors, model_ok)


def _check_attach(
    planner: PlannerConfig,
    task: TaskTemplate | None,
    world: WorldConfig | None,
    source: str,
    errors: ErrorLog,
) -> None:
    """An attachment needs a task state to follow, a free object, and the CPU rollouts (the
    warp backend's model is not changed between iterations)."""
    states = [st for f in task.factors for st in f.states] if task is not None else []
    free = [o.name for o in world.objects if not o.fixed] if world is not None else None
    for i, a in enumerate(planner.model.attach):
        path = f"planner.model.attach[{i}]"
        if a.state not in states:
            errors.add(
                ConfigError(
                    source,
                    f"{path}.while",
                    "not a state of the task's factors",
                    a.state,
                    "one of: " + ", ".join(states)
                    if states
                    else "a scenario with a task: template",
                )
            )
        if free is not None and a.object not in free:
            errors.add(
                ConfigError(
                    source,
                    f"{path}.object",
                    "not a free object of the world",
                    a.object,
                    "one of: " + (", ".join(free) or "(none)"),
                )
            )
    if planner.backend != "mujoco":
        errors.add(
            ConfigError(
                source,
                "planner.model.attach",
                "only the mujoco backend changes its model between iterations",
                planner.backend,
                "planner.backend: mujoco, or no attach",
            )
        )


def _observers(
    s: Section, task: TaskTemplate, errors: ErrorLog, plugins: bool = False
) -> dict[str, ObserverConfig]:
    """``factor: {predicate: {...}}`` (true -> first state, false -> second), or
    ``factor: [{state: s, when: {predicate: {...}}}, ..., {default: s}]``. Each factor's
    faults are collected in ``errors``. ``plugins``: the scenario names plugins, whose
    predicates the planner resolves once it imported them (``PluginPredicate``)."""
    out = {}
    for factor in task.factors:
        observer = errors.call(_observer, s, factor, plugins)
        if observer is not None:
            out[factor.name] = observer
    s.done()
    return out


def _observer(s: Section, factor: FactorTemplate, plugins: bool = False) -> ObserverConfig:
    """One task factor's observer (see :func:`_observers`)."""
    if not s.has(factor.name):
        raise s.error(
            factor.name,
            "missing observer for task factor",
            expected="a predicate or a list of {state, when} rules ending with {default: state}",
        )
    value = s.data[factor.name]
    states = factor.states
    if isinstance(value, dict):
        if len(states) != 2:
            raise s.error(
                factor.name,
                "the one-predicate form needs a two-state factor",
                list(states),
                "a list of {state, when} rules",
            )
        pred = parse_predicate(s.section(factor.name), plugins)
        return ObserverConfig(((states[0], pred),), states[1])
    rules, default = [], None
    for i, rule in enumerate(s.items(factor.name, required=True)):
        if rule.has("default"):
            default = rule.req("default", one_of(states))
            rule.done()
            if i != len(s.data[factor.name]) - 1:
                raise rule.error("default", "must be the last rule")
            continue
        state = rule.req("state", one_of(states))
        rules.append((state, parse_predicate(rule.section("when"), plugins)))
        rule.done()
    if default is None:
        raise s.error(factor.name, "the rule list needs a final {default: state}")
    return ObserverConfig(tuple(rules), default)


def _action_objectives(s: Section, task: TaskTemplate, objectives: dict) -> dict[str, str]:
    """The plan interface (paper II.D): every task action -> the objective that executes it."""
    out = {}
    for action in task.actions():
        out[action.name] = s.req(
            action.name, one_of(objectives), f"an objective: {', '.join(objectives)}"
        )
    s.done()
    return out


def _robot(s: Section) -> RobotConfig:
    """``robot:``: ``model:`` a robot's name (``m3p2i list robots``) or the path of a robot file
    (relative to the scenario's folder), or the keys of a robot file themselves (``mjcf``,
    ``frame``, ``controls``, ...; the MJCF relative to the scenario's folder); ``qpos``: the
    initial joint positions."""
    folder = Path(s.source).parent
    inline = [k for k in ROBOT_KEYS if s.has(k)]
    if inline and s.has("model"):
        raise s.error(
            inline[0],
            "a robot is either named (model:) or declared here, not both",
            expected="model: NAME, or the keys of a robot file (mjcf, frame, controls, ...)",
        )
    if inline:
        mjcf = s.data.get("mjcf")
        spec = parse_robot(s, Path(mjcf).stem if isinstance(mjcf, str) else "robot", folder)
        model = spec.name
    else:
        model = s.req(
            "model", str, "a robot's name, a robot file, or the robot's own keys (mjcf, ...)"
        )
        spec = _named_robot(s, model, folder)
    qpos = s.opt("qpos", None, vector(), "a list of numbers")
    s.done()
    return RobotConfig(model=model, qpos=qpos, spec=spec)


def _named_robot(s: Section, model: str, folder: Path) -> RobotSpec:
    """``robot.model``: a robot file's path (relative to the scenario's folder first),
    ``NAME.yaml`` in the ``robots`` folder beside the scenario's folder, then a robot by name
    (:func:`shared.robots.get_robot`: the user's robot folders, the shipped robots). A faulty
    robot file raises its own error (its file, key and value)."""
    if model.endswith((".yaml", ".yml")) or "/" in model or os.sep in model:
        for path in (folder / model, Path(model)):
            if path.is_file():
                return load_robot(path)
        raise s.error("model", "no such robot file", model, f"a file; looked in {folder}")
    beside = folder.parent / "robots" / f"{model}.yaml"
    if beside.is_file():
        return load_robot(beside)
    try:
        return get_robot(model)
    except KeyError:
        raise s.error(
            "model",
            "unknown robot",
            model,
            f"one of: {', '.join(sorted(ROBOTS))}, or a robot file (a path relative to the "
            "scenario)",
        ) from None


def _world(s: Section, errors: ErrorLog) -> WorldConfig | None:
    """The world, or None when a fault of it was recorded in ``errors`` (the model of a faulty
    world is not the file's; :func:`_declared_world` stands in for it in name checks). Every
    fault of the section is recorded, not only the first."""
    n_before = len(errors.errors)
    timestep = errors.call(s.req, "timestep", _timestep, _TIMESTEP)
    arena = errors.call(lambda: _arena(s.section("arena"))) if s.has("arena") else None
    battery = errors.call(lambda: _battery(s.section("battery"))) if s.has("battery") else None
    objects = []
    names: set[str] = set()
    for o in errors.call(s.items, "objects", default=[]):
        obj = errors.call(_object, o)
        if obj is None:
            continue
        if obj.name in names or obj.name == "robot":
            errors.add(
                o.error("name", "duplicate or reserved object name", obj.name, "a unique name")
            )
            continue
        names.add(obj.name)
        objects.append(obj)
    if battery and battery.charger not in names:
        errors.add(
            ConfigError(
                s.source,
                f"{s.path}.battery.charger",
                "not an object of this world",
                battery.charger,
                f"one of: {', '.join(sorted(names))}",
            )
        )
    by_name = {o.name: o for o in objects}
    randomize = tuple(
        errors.call(_randomize, r, by_name) for r in errors.call(s.items, "randomize", default=[])
    )
    disturbances = tuple(
        errors.call(_disturbance, d, by_name)
        for d in errors.call(s.items, "disturbances", default=[])
    )
    errors.call(s.done)
    if len(errors.errors) > n_before:
        return None
    return WorldConfig(
        timestep=timestep,
        objects=tuple(objects),
        arena=arena,
        battery=battery,
        randomize=randomize,
        disturbances=disturbances,
    )


def _arena(a: Section) -> ArenaConfig:
    arena = ArenaConfig(
        half_size=a.opt("half_size", 4.0, positive), wall_height=a.opt("wall_height", 0.3, positive)
    )
    if a.opt("wall_thickness", None, positive) is not None:  # older files: walls are planes
        deprecated(f"{a.path}.wall_thickness (in {a.source})", "remove it (walls are planes)")
    a.done()
    return arena


def _battery(b: Section) -> BatteryConfig:
    battery = BatteryConfig(
        charger=b.req("charger", str),
        rate=b.req("rate", positive, "%/s"),
        radius=b.opt("radius", 0.5, positive),
        initial=b.opt("initial", 100.0, non_negative),
    )
    b.done()
    return battery


def _declared_world(data: Any, source: str) -> WorldConfig:
    """A stand-in for a faulty ``world:`` section, for name checks only (its model is not the
    file's): the objects that read cleanly; each other object that has a name, as a small
    sphere of that name; the arena's walls (of the default size when the arena is faulty); the
    randomisations and disturbances that read cleanly. Its faults were recorded by
    :func:`_world`; none is recorded again."""
    scratch = ErrorLog()
    s = Section(data if isinstance(data, dict) else {}, source, "world")
    objects: list[ObjectConfig] = []
    for o in scratch.call(s.items, "objects", default=[]):
        obj = scratch.call(_object, o)
        name = obj.name if obj is not None else o.data.get("name")
        if (
            not isinstance(name, str)
            or not name
            or name == "robot"
            or name in {b.name for b in objects}
        ):
            continue
        fixed = o.data.get("fixed", True)
        objects.append(
            obj
            or ObjectConfig(
                name=name,
                shape="sphere",
                size=(0.05,),
                pos=(0.0, 0.0, 0.05),
                fixed=fixed if isinstance(fixed, bool) else True,
            )
        )
    by_name = {o.name: o for o in objects}
    arena = None
    if s.has("arena"):
        arena = scratch.call(lambda: _arena(s.section("arena")), default=ArenaConfig())
    parts = {}
    for key, read in (("randomize", _randomize), ("disturbances", _disturbance)):
        parts[key] = tuple(
            p
            for p in (
                scratch.call(read, i, by_name) for i in scratch.call(s.items, key, default=[])
            )
            if p is not None
        )
    timestep = scratch.call(s.req, "timestep", positive, default=None)
    return WorldConfig(
        timestep=timestep or 0.01,
        objects=tuple(objects),
        arena=arena,
        randomize=parts["randomize"],
        disturbances=parts["disturbances"],
    )


def _object_ref(s: Section, by_name: dict[str, ObjectConfig], fixed: bool | None = None) -> str:
    name = s.req("object", str)
    if name not in by_name:
        raise s.error(
            "object", "not an object of this world", name, f"one of: {', '.join(sorted(by_name))}"
        )
    if fixed is not None and by_name[name].fixed != fixed:
        raise s.error(
            "object",
            "must be a fixed object (moved kinematically)" if fixed else "must be a free object",
            name,
        )
    return name


def _range(value) -> tuple[float, float]:
    lo, hi = vector(2)(value)
    if lo > hi:
        raise ValueError("low > high")
    return lo, hi


def _waypoint(s: Section, i: int, value, key: str = "waypoints") -> tuple[float, float, float]:
    try:
        return vector(3)(value)
    except ValueError as exc:
        raise ConfigError(
            s.source, f"{s.key_path(key)}[{i}]", str(exc), value, "[x, y, z]"
        ) from None


def _randomize(s: Section, by_name) -> RandomizeConfig:
    choose = None
    if s.has("choose"):
        points = s.req("choose", list, "a list of [x, y, z] start positions")
        if len(points) < 2:
            raise s.error("choose", "needs at least two start positions", points)
        for axis in ("x", "y"):
            if s.has(axis):
                raise s.error(axis, "give either choose or x/y ranges, not both", s.data[axis])
        choose = tuple(_waypoint(s, i, p, "choose") for i, p in enumerate(points))
    cfg = RandomizeConfig(
        object=_object_ref(s, by_name),
        x=s.opt("x", None, _range, "[low, high]"),
        y=s.opt("y", None, _range, "[low, high]"),
        yaw=s.opt("yaw", None, _range, "[low, high] degrees"),
        choose=choose,
    )
    s.done()
    return cfg


def _disturbance(s: Section, by_name) -> MoveConfig | PathConfig:
    kinds = [k for k in ("move", "path") if s.has(k)]
    if len(kinds) != 1:
        raise ConfigError(
            s.source, s.path, "a disturbance needs exactly one of: move, path", sorted(s.data)
        )
    if kinds[0] == "move":
        m = s.section("move")
        when = parse_predicate(m.section("when")) if m.has("when") else None
        delay = m.opt("delay", 0.0, non_negative, "seconds >= 0")
        if delay and when is None:
            raise m.error(
                "delay",
                "a delay counts from when the `when` condition first holds; "
                "give `when`, or use `at` alone",
                delay,
            )
        cfg = MoveConfig(
            object=_object_ref(m, by_name),
            at=m.opt("at", 0.0, non_negative),
            when=when,
            pos=m.opt("pos", None, vector(3), "[x, y, z]"),
            yaw=m.opt("yaw", None, number, "degrees"),
            delay=delay,
        )
    else:
        m = s.section("path")
        points = m.req("waypoints", list, "a list of [x, y, z]")
        if len(points) < 2:
            raise m.error("waypoints", "needs at least two waypoints", points)
        cfg = PathConfig(
            object=_object_ref(m, by_name, fixed=True),
            waypoints=tuple(_waypoint(m, i, p) for i, p in enumerate(points)),
            speed=m.req("speed", positive, "m/s"),
            start=m.opt("start", 0.0, non_negative),
            loop=m.opt("loop", True, bool),
        )
    m.done()
    s.done()
    return cfg


def _object(s: Section) -> ObjectConfig:
    name = s.req("name", str)
    shape = s.req("shape", one_of(SHAPES))
    size = s.req("size", vector(_SIZE_LEN[shape]), f"{_SIZE_LEN[shape]} half-sizes for a {shape}")
    if not all(v > 0 for v in size):
        raise s.error("size", "sizes must be > 0", list(size))
    visual = s.opt("visual", False, bool)
    obj = ObjectConfig(
        name=name,
        shape=shape,
        size=size,
        pos=s.req("pos", vector(3), "[x, y, z] in metres"),
        yaw=s.opt("yaw", 0.0, number),
        fixed=s.opt("fixed", True, bool),
        mass=s.opt("mass", 1.0, positive),
        friction=s.opt("friction", 0.5, non_negative),
        rgba=s.opt("rgba", (0.6, 0.6, 0.6, 1.0), vector(4), "[r, g, b, a] in 0..1"),
        visual=visual,
        obstacle=s.opt("obstacle", not visual, bool),
    )
    s.done()
    return obj


def _episode(s: Section, errors: ErrorLog) -> EpisodeConfig:
    """The episode; a faulty success predicate is recorded in ``errors``, and then the whole
    success test is left out (so later checks never name a shifted index)."""
    max_time = errors.call(s.req, "max_time", positive, "seconds of simulated time", default=0.0)
    items = s.items("success", required=True)
    if not items:
        raise s.error("success", "needs at least one predicate", [])
    parsed = [errors.call(parse_predicate, i) for i in items]
    success = tuple(parsed) if None not in parsed else ()
    hold = errors.call(s.opt, "hold", 0.0, non_negative, "seconds >= 0", default=0.0)
    errors.call(s.done)
    return EpisodeConfig(max_time=max_time, success=success, hold=hold)


def _metrics(s: Section, episode: EpisodeConfig) -> MetricsConfig:
    """``metrics: {position: {a, b, axes, offset}, orientation: {a, b}, collisions: {a, with}}``.
    Without ``position``/``orientation``, what success is judged on: the first ``near`` or
    ``at_pose`` success predicate (an ``at_pose`` with an orientation tolerance also gives the
    orientation)."""
    judged = next((p for p in episode.success if p.kind in ("near", "at_pose")), None)
    if s.has("position"):
        position = _frame_pair(s.section("position"), position=True)
    elif judged is None:
        position = None
    elif judged.kind == "near":
        position = FramePairConfig(judged.a, judged.b, judged.axes)
    else:
        position = FramePairConfig(judged.a, judged.b, offset=judged.offset)
    if s.has("orientation"):
        orientation = _frame_pair(s.section("orientation"), position=False)
    elif judged is not None and judged.kind == "at_pose" and judged.orientation is not None:
        orientation = FramePairConfig(judged.a, judged.b)
    else:
        orientation = None
    collisions = None
    if s.has("collisions"):
        c = s.section("collisions")
        collisions = CollisionMetricConfig(
            a=c.req("a", string_list, "a frame name or a list of them (robot, an object)"),
            with_=c.req("with", string_list, "a list of body names (e.g. a dynamic obstacle)"),
        )
        c.done()
    s.done()
    return MetricsConfig(position=position, orientation=orientation, collisions=collisions)


def _frame_pair(s: Section, position: bool) -> FramePairConfig:
    a, b = s.req("a", str, "a frame name"), s.req("b", str, "a frame name")
    if not position:
        s.done()
        return FramePairConfig(a, b)
    pair = FramePairConfig(
        a,
        b,
        axes=s.opt("axes", "xyz", one_of(AXES)),
        offset=s.opt("offset", (0.0, 0.0, 0.0), vector(3), "[x, y, z] in metres"),
    )
    s.done()
    return pair


def _planner(s: Section) -> PlannerConfig:
    cfg = PlannerConfig(
        samples=s.opt("samples", 200, positive_int),
        horizon=s.opt("horizon", 15, positive_int),
        mppi=dict(s.section("mppi", required=False).data),
        threads=s.opt("threads", 0, int),
        aip_period=s.opt("aip_period", 0.2, positive, "simulated seconds"),
        confirm=s.opt(
            "confirm",
            {},
            _confirm_times,
            "seconds >= 0, or a map {factor: seconds or {state: seconds}, '*': seconds}",
        ),
        timestep=s.opt("timestep", None, _timestep, f"{_TIMESTEP}, a multiple of world.timestep"),
        backend=s.opt("backend", "mujoco", one_of(ROLLOUT_BACKENDS)),
        device=s.opt("device", "cuda:0", rollout_device, "cpu, cuda or cuda:N"),
        nconmax=s.opt("nconmax", None, positive_int, "contacts per world"),
        njmax=s.opt("njmax", None, positive_int, "constraint rows per world"),
        model=_planning_model(s.section("model", required=False)),
        estimate=_estimate(s.section("estimate", required=False)),
        delays=_delays(s.section("delays", required=False)),
    )
    s.done()
    _check_variants(s, cfg)
    return cfg


def _check_variants(s: Section, cfg: PlannerConfig) -> None:
    """``planner.model.variants`` against the rest of ``planner``: MJWarp rolls out one model
    for all its worlds, and a split needs a sample per variant in every mode."""
    v = cfg.model.variants
    if v is None:
        return
    path = "model.variants"
    if cfg.backend != "mujoco":
        raise s.error(
            path,
            f"the {cfg.backend} backend rolls out one model for all samples",
            v.as_dict(),
            "backend: mujoco (mujoco.rollout takes a model per rollout), or no variants",
        )
    if v.spread == "split" and v.count > cfg.samples:
        raise s.error(
            f"{path}.count",
            f"{v.count} variants split over planner.samples = {cfg.samples} per mode",
            v.count,
            f"count <= {cfg.samples} (or spread: all)",
        )


def _delays(s: Section) -> DelayConfig:
    cfg = DelayConfig(
        actuation_ms=s.opt("actuation_ms", 0.0, non_negative, "milliseconds >= 0"),
        state_ms=s.opt("state_ms", 0.0, non_negative, "milliseconds >= 0"),
        estimate=s.opt("estimate", False, flag, "true or false"),
        max_ms=s.opt("max_ms", 300.0, positive, "milliseconds > 0"),
    )
    s.done()
    return cfg


def _planning_model(s: Section) -> PlanningModel:
    cfg = PlanningModel(
        solver=s.opt("solver", None, one_of(SOLVERS)),
        iterations=s.opt("iterations", None, positive_int),
        ls_iterations=s.opt("ls_iterations", None, positive_int),
        tolerance=s.opt("tolerance", None, non_negative, "a number >= 0 (0: no early stop)"),
        cone=s.opt("cone", None, one_of(CONES)),
        noslip_iterations=s.opt("noslip_iterations", None, _count, "an integer >= 0"),
        integrator=s.opt("integrator", None, one_of(INTEGRATORS)),
        condim=s.opt("condim", None, _one_of_ints((1, 3, 4, 6)), "1, 3, 4 or 6"),
        exclude=tuple(s.opt("exclude", (), _body_pairs, "a list of [body, body] pairs")),
        attach=tuple(_attach(a) for a in s.items("attach")),
        objects=_object_models(s.section("objects", required=False)),
        geoms=_geom_models(s.section("geoms", required=False)),
        variants=_variants(s.section("variants")) if s.has("variants") else None,
    )
    s.done()
    return cfg


def _fraction(value: Any) -> float:
    v = non_negative(value)
    if v >= 1:
        raise ValueError("must be < 1")
    return v


_FRACTION = "a fraction in [0, 1) (0.3: factors within ±30 %)"

# the longest prediction the identifier scores, in world steps: the controller keeps the plans
# sent over that span (planner_client.controller)
MAX_IDENTIFY_WINDOW = 20


def _window(value: Any) -> int:
    v = positive_int(value)
    if v > MAX_IDENTIFY_WINDOW:
        raise ValueError(f"must be <= {MAX_IDENTIFY_WINDOW}")
    return v


def _variants(s: Section) -> VariantsConfig:
    p = s.section("params")
    params = {k: p.opt(k, 0.0, _fraction, _FRACTION) for k in VARIANT_PARAMS}
    p.done()
    if not any(params.values()):
        raise s.error(
            "params",
            "no parameter varies",
            dict(p.data),
            "at least one of " + ", ".join(f"{k}: f" for k in VARIANT_PARAMS) + f" ({_FRACTION})",
        )
    cfg = VariantsConfig(
        count=s.opt("count", 8, positive_int, "an integer >= 1 (models)"),
        seed=s.opt("seed", 0, _count, "an integer >= 0"),
        spread=s.opt("spread", "split", one_of(VARIANT_SPREADS)),
        aggregate=s.opt("aggregate", "mean", one_of(VARIANT_AGGREGATES)),
        cvar_alpha=s.opt("cvar_alpha", 0.25, _weight, "a share in (0, 1]"),
        identify=_identify(s.section("identify")) if s.has("identify") else None,
        **params,
    )
    if cfg.spread != "all" and s.has("aggregate"):
        raise s.error(
            "aggregate",
            "an aggregate needs every sample rolled out in every variant",
            cfg.aggregate,
            f"spread: all (with spread: {cfg.spread} each sample meets one model)",
        )
    if cfg.spread == "estimate" and cfg.identify is None:
        raise s.error(
            "spread",
            "rollouts at the identified factors need the variants identified",
            cfg.spread,
            "an identify section (e.g. identify: {}), or spread: split or all",
        )
    s.done()
    return cfg


def _identify(s: Section) -> IdentifyConfig:
    cfg = IdentifyConfig(
        position_sigma=s.opt("position_sigma", 0.005, positive, "metres > 0"),
        velocity_sigma=s.opt("velocity_sigma", 0.02, positive, "m/s (rad/s) > 0"),
        forget=s.opt("forget", 0.9, _weight, "a share in (0, 1]"),
        floor=s.opt("floor", 0.1, _fraction, "a share in [0, 1)"),
        jitter=s.opt("jitter", 0.1, non_negative, "a fraction >= 0 of the prior's half-width"),
        window=s.opt("window", 1, _window, f"steps, an integer in [1, {MAX_IDENTIFY_WINDOW}]"),
    )
    s.done()
    return cfg


def _sizes(value: Any) -> tuple[float, ...]:
    v = vector()(value)
    if not 1 <= len(v) <= 3 or not all(x > 0 for x in v):
        raise ValueError("must be 1 to 3 numbers > 0")
    return v


def _named_sections(s: Section, what: str):
    """``(name, section)`` for each key of ``s``, a mapping of names to mappings."""
    for name in s.data:
        if not isinstance(name, str):
            raise s.error(str(name), "wrong type", name, what)
        yield name, s.section(name)


def _geom_models(s: Section) -> dict[str, GeomModel]:
    out = {}
    for name, g in _named_sections(s, "a geom's name"):
        out[name] = GeomModel(
            type=g.opt("type", None, one_of(GEOM_TYPES)),
            size=g.opt("size", None, _sizes, "1 to 3 numbers > 0, as MuJoCo's geom size"),
            pos=g.opt("pos", None, vector(3), "[x, y, z] in metres, in the body's frame"),
        )
        g.done()
    s.done()
    return out


_PER_DOF = "a number >= 0 (all six DOFs) or six: [x, y, z, rx, ry, rz]"


def _per_dof(value: Any) -> tuple[float, ...]:
    """One number for all six DOFs of a free joint, or six (:data:`FREE_DOFS` order), each >= 0."""
    values = [value] * len(FREE_DOFS) if not isinstance(value, (list, tuple)) else value
    if len(values) != len(FREE_DOFS):
        raise ValueError(f"needs {len(FREE_DOFS)} numbers")
    return tuple(non_negative(v) for v in values)


def _object_models(s: Section) -> dict[str, ObjectModel]:
    out = {}
    for name, o in _named_sections(s, "an object's name"):
        out[name] = ObjectModel(
            gravcomp=o.opt("gravcomp", None, non_negative, "a number >= 0 (1: weight cancelled)"),
            damping=o.opt("damping", None, _per_dof, _PER_DOF),
            frictionloss=o.opt("frictionloss", None, _per_dof, _PER_DOF),
            armature=o.opt("armature", None, _per_dof, _PER_DOF),
            planar=o.opt("planar", False, flag, "true or false"),
        )
        o.done()
    s.done()
    return out


def _attach(s: Section) -> Attach:
    cfg = Attach(
        object=s.req("object", str, "a free object's name"),
        to=s.req("to", str, "a body of the robot"),
        state=s.req("while", str, "a state of a task factor, e.g. holding"),
    )
    s.done()
    return cfg


def _estimate(s: Section) -> EstimateConfig:
    cfg = EstimateConfig(
        object_velocities=s.opt(
            "object_velocities", "received", one_of(("received", "from_poses"))
        ),
        pose_filter=s.opt("pose_filter", 1.0, _weight, "a weight in (0, 1]"),
        velocity_filter=s.opt("velocity_filter", 1.0, _weight, "a weight in (0, 1]"),
        max_speed=s.opt("max_speed", 5.0, positive, "m/s > 0"),
        held_filter=s.opt("held_filter", 1.0, _weight, "a weight in (0, 1]"),
        still_speed=s.opt("still_speed", 0.0, non_negative, "m/s >= 0"),
        predict=s.opt("predict", False, flag, "true or false"),
    )
    s.done()
    return cfg


_TIMESTEP = "seconds in [1e-06, 10]"


def _timestep(value: Any) -> float:
    """A world's or a planning step: a microsecond to ten seconds (beyond, no simulation; a
    subnormal one made every count of steps overflow)."""
    v = number(value)
    if not 1e-6 <= v <= 10.0:
        raise ValueError("must be between a microsecond and 10 s")
    return v


def _weight(value: Any) -> float:
    v = number(value)
    if not 0.0 < v <= 1.0:
        raise ValueError("must be in (0, 1]")
    return v


def _confirm_times(value: Any) -> dict[str, float | dict[str, float]]:
    """``seconds``, or ``{factor: seconds | {state: seconds}, '*': seconds}``: a factor's
    mapping gives the time a change *to* each listed state must persist (unlisted: at once),
    so one direction can be quick and the other slow (hysteresis)."""
    if not isinstance(value, dict):
        return {"*": non_negative(value)}
    if not all(isinstance(k, str) for k in value):
        raise ValueError("wrong type")
    out: dict[str, float | dict[str, float]] = {}
    for k, v in value.items():
        if isinstance(v, dict) and k != "*":
            if not all(isinstance(state, str) for state in v):
                raise ValueError("wrong type")
            out[k] = {state: non_negative(t) for state, t in v.items()}
        else:
            out[k] = non_negative(v)
    return out


def _count(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError("must be an integer >= 0")
    return value


def _one_of_ints(choices: tuple[int, ...]):
    def convert(value: Any) -> int:
        if isinstance(value, bool) or value not in choices:
            raise ValueError(f"must be one of: {', '.join(map(str, choices))}")
        return value

    return convert


def _body_pairs(value: Any) -> list[tuple[str, str]]:
    if not isinstance(value, list) or not all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(b, str) for b in p) for p in value
    ):
        raise ValueError("wrong type")
    return [(a, b) for a, b in value]


def _includes(top: Section, errors: ErrorLog) -> tuple[dict[str, ObjectiveConfig], list[dict]]:
    """``include: [NAME or path, ...]``: files of named objectives (``objectives/NAME.yaml``)
    that this scenario's objectives may ``extends``; their contents, for the hash."""
    names = errors.call(
        top.opt,
        "include",
        (),
        string_list,
        "a list of objective files: names (objectives/NAME.yaml) or paths",
        default=(),
    )
    library: dict[str, ObjectiveConfig] = {}
    contents = []
    for i, name in enumerate(names):
        try:
            path = find_objectives(name)
            raw = load_yaml(path)
        except ConfigError as exc:
            errors.add(
                ConfigError(
                    top.source,
                    f"include[{i}]",
                    exc.message,
                    name,
                    exc.expected or "an objectives file",
                )
            )
            continue
        contents.append(raw)
        s = Section(raw, str(path))
        errors.call(s.opt, "description", "", str)
        defined = errors.call(
            lambda s=s: _objectives(s.section("objectives"), errors, library), default={}
        )
        errors.call(s.done)
        for key in defined:
            if key in library:
                errors.add(
                    ConfigError(
                        str(path),
                        f"objectives.{key}",
                        "defined in two included files",
                        key,
                        "a unique name",
                    )
                )
        library.update(defined)
    return library, contents


def _objectives(
    s: Section, errors: ErrorLog, library: dict[str, ObjectiveConfig]
) -> dict[str, ObjectiveConfig]:
    """Every objective of the mapping at ``s``; a faulty term or ``fixed`` value is recorded in
    ``errors`` and left out, so the planner's checks of the other terms still run.

    ``NAME: {extends: BASE, terms: [...], fixed: {...}}`` starts from objective BASE (of an
    included file, or defined above in the same mapping): its terms, then these; its ``fixed``
    controls, updated with these."""
    out: dict[str, ObjectiveConfig] = {}
    for name in s.data:
        o = errors.call(s.section, name)
        if o is None:
            continue
        known = {**library, **out}
        base = ObjectiveConfig(terms=())
        if o.has("extends"):
            base_name = errors.call(
                o.req, "extends", one_of(known), "an objective of an included file or defined above"
            )
            if base_name is None:
                o.opt("terms", None)  # the extends error is the one to report
                o.opt("fixed", None)
                continue
            base = known[base_name]
            items = errors.call(o.items, "terms", default=[])
        else:
            items = errors.call(o.items, "terms", required=True, default=[])
        terms = tuple(t for t in (errors.call(_term, t) for t in items) if t is not None)
        fixed = errors.call(o.opt, "fixed", {}, dict, "a mapping actuator -> value", default={})
        numbers = {}
        for k, v in fixed.items():
            try:
                numbers[k] = number(v)
            except ValueError:
                errors.add(
                    ConfigError(s.source, f"{o.path}.fixed.{k}", "must be a finite number", v)
                )
        errors.call(o.done)
        out[name] = ObjectiveConfig(terms=base.terms + terms, fixed={**base.fixed, **numbers})
    if not s.data:
        raise ConfigError(s.source, s.path, "needs at least one objective", {})
    return out


def _term(t: Section) -> TermConfig:
    term = t.req("term", str)
    weight = t.opt("weight", 1.0, number, "a number")
    params = {k: v for k, v in t.data.items() if k not in ("term", "weight")}
    return TermConfig(term=term, weight=weight, params=params, path=t.path, source=t.source)
