"""The ``world`` section: the step, the arena and its walls, the objects, randomised starts,
scripted disturbances and the battery."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from shared.config import (
    ConfigError,
    ErrorLog,
    Section,
    deprecated,
    non_negative,
    number,
    one_of,
    positive,
    vector,
)
from shared.predicates import Predicate, parse_predicate
from shared.scenario.common import STEP_SECONDS, step_seconds

SHAPES = ("box", "cylinder", "sphere")


_SIZE_LEN = {"box": 3, "cylinder": 2, "sphere": 1}


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
    # unknown to the planner: the world simulates it (fixed or free), the planner's model lacks
    # it, and only the sensors' scans show it (planner_client.problem.planner_scenario)
    perceived: bool = False


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

    def span(self) -> tuple[float, float]:
        """Width and depth (m, x and y) of what the world declares: its arena and its objects,
        each object as the square its largest half-size bounds."""
        xs, ys = [], []
        if self.arena is not None:
            xs += [-self.arena.half_size, self.arena.half_size]
            ys += [-self.arena.half_size, self.arena.half_size]
        for o in self.objects:
            r = max(o.size)
            xs += [o.pos[0] - r, o.pos[0] + r]
            ys += [o.pos[1] - r, o.pos[1] + r]
        if not xs:
            return (0.0, 0.0)
        return (max(xs) - min(xs), max(ys) - min(ys))


def read_world(s: Section, errors: ErrorLog) -> WorldConfig | None:
    """The world, or None when a fault of it was recorded in ``errors`` (the model of a faulty
    world is not the file's; :func:`declared_world` stands in for it in name checks). Every
    fault of the section is recorded, not only the first."""
    n_before = len(errors.errors)
    timestep = errors.call(s.req, "timestep", step_seconds, STEP_SECONDS)
    arena = errors.call(lambda: _arena(s.section("arena"))) if s.has("arena") else None
    battery = errors.call(lambda: _battery(s.section("battery"))) if s.has("battery") else None
    objects = []
    names: set[str] = set()
    for o in errors.call(s.items, "objects", default=[]):
        obj = errors.call(_object, o)
        if obj is None:
            continue
        if arena is not None and max(abs(obj.pos[0]), abs(obj.pos[1])) > arena.half_size:
            # a goal out there passed every check, and the episode timed out
            errors.add(
                o.error(
                    "pos",
                    f"outside the arena, whose walls stand at ±{arena.half_size:g} m",
                    list(obj.pos),
                    f"|x| and |y| <= {arena.half_size:g} (or a larger world.arena.half_size)",
                )
            )
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


def declared_world(data: Any, source: str) -> WorldConfig:
    """A stand-in for a faulty ``world:`` section, for name checks only (its model is not the
    file's): the objects that read cleanly; each other object that has a name, as a small
    sphere of that name; the arena's walls (of the default size when the arena is faulty); the
    randomisations and disturbances that read cleanly. Its faults were recorded by
    :func:`read_world`; none is recorded again."""
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
        perceived=s.opt("perceived", False, bool),
    )
    if obj.perceived and obj.visual:  # a marker collides with nothing: no sensor sees it
        raise s.error("perceived", "a visual object cannot be perceived", True, "visual: false")
    s.done()
    return obj
