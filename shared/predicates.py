"""Logical predicates over the continuous world state, named in YAML.

They serve twice: the server's success test (all of ``episode.success`` must hold) and the
planner's symbolic observers (paper Eqs. 13, 23-26; thesis Eq. 4.3), which turn a predicate's
truth into a discrete observation for active inference. Each predicate is a small frozen
dataclass built from its YAML parameters, validated at scenario load; frame names are checked
against the compiled model by :meth:`Predicate.bind`.

Add one with ``@register("name")`` on a class with ``from_section`` and ``holds``; a module of
the user's may too, for the planner's observers (:class:`PluginPredicate`, docs/cost_terms.md).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np

from shared.config import ConfigError, ErrorLog, Section, non_negative, number, one_of, vector
from shared.frames import Frame, FrameResolver
from shared.geometry import AXES, select_axes, symmetric_orientation_error

PREDICATES: dict[str, type[Predicate]] = {}


def register(name: str) -> Callable[[type], type]:
    """Class decorator: make a predicate available to YAML as ``name: {...}``, once (a second
    predicate of the same name is refused, naming both classes)."""

    def wrap(cls: type) -> type:
        if name in PREDICATES and PREDICATES[name] is not cls:
            old = PREDICATES[name]
            raise ValueError(
                f"predicate {name!r} registered twice: by {old.__module__}.{old.__qualname__} "
                f"and by {cls.__module__}.{cls.__qualname__}; give the new one another name"
            )
        cls.kind = name
        PREDICATES[name] = cls
        return cls

    return wrap


@dataclass(frozen=True)
class WorldView:
    """What a predicate may look at: MuJoCo data (kinematics up to date) and named extras."""

    data: mujoco.MjData
    extras: dict[str, float]


class Predicate(ABC):
    """Base: a boolean function of the world. Subclasses are frozen dataclasses."""

    kind: ClassVar[str]
    frame_keys: ClassVar[tuple[str, ...]] = ()

    @classmethod
    @abstractmethod
    def from_section(cls, s: Section) -> Predicate:
        """Build from the predicate's YAML parameters."""

    def bind(self, resolve: FrameResolver) -> BoundPredicate:
        """Resolve frame names once; the result is called every tick."""
        return BoundPredicate(self, {k: resolve(getattr(self, k)) for k in self.frame_keys})

    @abstractmethod
    def holds(self, view: WorldView, frames: dict[str, Frame]) -> bool:
        """Truth of the predicate in ``view``, with this predicate's frames resolved."""

    def measure(self, view: WorldView, frames: dict[str, Frame]) -> dict[str, float]:
        """Quantities worth reporting (e.g. ``distance robot-goal``); none by default."""
        return {}


@dataclass(frozen=True)
class BoundPredicate:
    predicate: Predicate
    frames: dict[str, Frame]

    def __call__(self, view: WorldView) -> bool:
        return bool(self.predicate.holds(view, self.frames))

    def measures(self, view: WorldView) -> dict[str, float]:
        """Named quantities behind the truth value, for episode summaries."""
        return self.predicate.measure(view, self.frames)


def _axes(value: Any) -> str:
    return one_of(AXES)(value)


def _distance(a: np.ndarray, b: np.ndarray, axes: str) -> float:
    return float(np.linalg.norm(select_axes(a - b, axes)))


class _PairDistance:
    """What ``near`` and ``far`` share: the distance between frames ``a`` and ``b`` along
    ``axes``, reported as ``distance a-b``."""

    a: str
    b: str
    axes: str

    def distance(self, view, frames) -> float:
        return _distance(frames["a"].pos(view.data), frames["b"].pos(view.data), self.axes)

    def measure(self, view, frames):
        return {f"distance {self.a}-{self.b}": self.distance(view, frames)}


@register("near")
@dataclass(frozen=True)
class Near(_PairDistance, Predicate):
    """|x_a - x_b| <= within (paper Eq. 13, paper Eq. 23); ``axes: xy`` ignores height."""

    a: str
    b: str
    within: float
    axes: str = "xyz"
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "b")

    @classmethod
    def from_section(cls, s: Section) -> Near:
        return cls(
            a=s.req("a", str),
            b=s.req("b", str),
            within=s.req("within", non_negative),
            axes=s.opt("axes", "xyz", _axes),
        )

    def holds(self, view, frames):
        return self.distance(view, frames) <= self.within


@register("far")
@dataclass(frozen=True)
class Far(_PairDistance, Predicate):
    """|x_a - x_b| > beyond: the negation of ``near`` for templates that need it by name."""

    a: str
    b: str
    beyond: float
    axes: str = "xyz"
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "b")

    @classmethod
    def from_section(cls, s: Section) -> Far:
        return cls(
            a=s.req("a", str),
            b=s.req("b", str),
            beyond=s.req("beyond", non_negative),
            axes=s.opt("axes", "xyz", _axes),
        )

    def holds(self, view, frames):
        return self.distance(view, frames) > self.beyond


@register("extra_at_least")
@dataclass(frozen=True)
class ExtraAtLeast(Predicate):
    """A named world extra (e.g. ``battery``) is >= ``value`` (thesis Eq. 4.3)."""

    name: str
    value: float

    @classmethod
    def from_section(cls, s: Section) -> ExtraAtLeast:
        return cls(name=s.req("name", str), value=s.req("value", number))

    def holds(self, view, frames):
        return view.extras.get(self.name, -np.inf) >= self.value

    def measure(self, view, frames):
        return {self.name: view.extras.get(self.name, float("nan"))}


@register("at_pose")
@dataclass(frozen=True)
class AtPose(Predicate):
    """Frame ``a`` at ``b`` shifted by ``offset`` (world frame, metres), in position and in
    orientation (paper Eqs. 25-26): |x_a - (x_b + offset)| < ``within`` and, when ``orientation`` is
    given, φ(Σ_a, Σ_b) < ``orientation`` with φ the symmetric-object metric of paper Eq. 33 (any of
    a cube's 24 symmetries counts as aligned). The offset places a goal relative to a movable
    object, e.g. "on top of cube B" is ``offset: [0, 0, 0.05]`` for 5 cm cubes."""

    a: str
    b: str
    within: float
    orientation: float | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "b")

    @classmethod
    def from_section(cls, s: Section) -> AtPose:
        return cls(
            a=s.req("a", str),
            b=s.req("b", str),
            within=s.req("within", non_negative),
            orientation=s.opt("orientation", None, non_negative, "phi tolerance >= 0"),
            offset=s.opt("offset", (0.0, 0.0, 0.0), vector(3), "[x, y, z] in metres"),
        )

    def errors(self, view, frames) -> tuple[float, float]:
        """(position error in metres, orientation error φ)."""
        d = view.data
        target = frames["b"].pos(d) + np.asarray(self.offset)
        phi = symmetric_orientation_error(frames["a"].rot(d), frames["b"].rot(d))
        return float(np.linalg.norm(frames["a"].pos(d) - target)), float(phi)

    def holds(self, view, frames):
        position, phi = self.errors(view, frames)
        return position < self.within and (self.orientation is None or phi < self.orientation)

    def measure(self, view, frames):
        position, phi = self.errors(view, frames)
        return {
            f"position error {self.a}-{self.b}": position,
            f"orientation error {self.a}-{self.b}": phi,
        }


@register("gripper_width_between")
@dataclass(frozen=True)
class GripperWidthBetween(Predicate):
    """low < |x_left - x_right| < high: the gripper holds an object of about that width
    (paper Eq. 24, l_gripper between the two fingertip frames)."""

    left: str
    right: str
    low: float
    high: float
    frame_keys: ClassVar[tuple[str, ...]] = ("left", "right")

    @classmethod
    def from_section(cls, s: Section) -> GripperWidthBetween:
        low, high = s.req("low", non_negative, "metres"), s.req("high", non_negative, "metres")
        if not low < high:
            raise s.error("high", "must be greater than low", high, f"a width > {low}")
        return cls(left=s.req("left", str), right=s.req("right", str), low=low, high=high)

    def width(self, view, frames) -> float:
        return float(np.linalg.norm(frames["left"].pos(view.data) - frames["right"].pos(view.data)))

    def holds(self, view, frames):
        return self.low < self.width(view, frames) < self.high

    def measure(self, view, frames):
        return {"gripper width": self.width(view, frames)}


@register("all")
@dataclass(frozen=True)
class All(Predicate):
    """Every listed predicate holds, e.g. a cube on its goal *and* the gripper open:
    ``all: [{at_pose: {...}}, {gripper_width_between: {...}}]``. For observers and disturbance
    triggers that need more than one condition (``episode.success`` is already such a list)."""

    parts: tuple[Predicate, ...]

    @classmethod
    def from_section(cls, s: Section) -> All:
        """``s`` is the mapping that holds ``all``: its parameters are a list, not a mapping."""
        parts = tuple(parse_predicate(p) for p in s.items("all", required=True))
        if not parts:
            raise s.error("all", "needs at least one predicate", [])
        return cls(parts)

    def bind(self, resolve: FrameResolver) -> BoundPredicate:
        # each part's frames, keyed "i.key", so one BoundPredicate carries the whole tree
        frames = {
            f"{i}.{k}": f
            for i, p in enumerate(self.parts)
            for k, f in p.bind(resolve).frames.items()
        }
        return BoundPredicate(self, frames)

    def _part_frames(self, i: int, frames: dict[str, Frame]) -> dict[str, Frame]:
        prefix = f"{i}."
        return {k[len(prefix) :]: f for k, f in frames.items() if k.startswith(prefix)}

    def holds(self, view, frames):
        return all(p.holds(view, self._part_frames(i, frames)) for i, p in enumerate(self.parts))

    def measure(self, view, frames):
        out: dict[str, float] = {}
        for i, p in enumerate(self.parts):
            out.update(p.measure(view, self._part_frames(i, frames)))
        return out


@dataclass(frozen=True, eq=False)  # its parameters are a mapping, not hashable
class PluginPredicate(Predicate):
    """A predicate that no module had registered when the scenario was read, in an observer of a
    scenario that names plugins: the planner imports them before it builds its observers
    (``planner_client.plugins``) and resolves it then (:meth:`resolved`); the world imports no
    plugin and never evaluates an observer. Its parameters are checked when it is resolved."""

    name: str
    params: Any
    source: str
    path: str

    kind: ClassVar[str] = "plugin"

    @classmethod
    def from_section(cls, s: Section) -> PluginPredicate:
        """From its parameters' section, whose key is the predicate's name."""
        return cls(s.path.rsplit(".", 1)[-1], s.data, s.source, s.path)

    def resolved(self) -> Predicate:
        """The registered predicate of this name built from the parameters, or the error of an
        unknown name (or of its parameters)."""
        if self.name not in PREDICATES:
            raise ConfigError(
                self.source,
                self.path,
                "unknown predicate",
                self.name,
                f"one of: {', '.join(sorted(PREDICATES))}; or a predicate of your own, from a "
                "module named by the scenario's plugins: or the planner's --plugins",
            )
        s = Section({self.name: self.params}, self.source, self.path.rpartition(".")[0])
        return parse_predicate(s)

    def bind(self, resolve: FrameResolver) -> BoundPredicate:
        return self.resolved().bind(resolve)

    def holds(self, view, frames):
        raise RuntimeError(f"predicate {self.name!r} was never resolved (plugins not imported)")


def parse_predicate(s: Section, plugins: bool = False) -> Predicate:
    """``{near: {a: robot, b: goal, within: 0.1}}`` -> a Predicate (one key: the predicate name).
    ``plugins``: the scenario names plugins and this is a planner-side predicate (an observer),
    so an unknown name is a :class:`PluginPredicate`, resolved once the planner imported them."""
    if len(s.data) != 1:
        raise ConfigError(
            s.source,
            s.path,
            "a predicate is a mapping with exactly one key",
            sorted(s.data),
            f"one of: {', '.join(sorted(PREDICATES))}",
        )
    (name,) = s.data
    if name not in PREDICATES and plugins:
        params = s.section(name, required=False)  # its parameters are checked once resolved
        s.done()
        return PluginPredicate.from_section(params)
    if name not in PREDICATES:
        raise s.error(name, "unknown predicate", name, f"one of: {', '.join(sorted(PREDICATES))}")
    if name == "all":
        pred = All.from_section(s)
    else:
        params = s.section(name)
        pred = PREDICATES[name].from_section(params)
        params.done()
    s.done()
    return pred


def check_frames(pred: Predicate, resolve: FrameResolver, source: str, path: str) -> None:
    """Load-time check that every frame a predicate names exists in the model; every missing
    frame of the predicate (and of the parts of an ``all``) is reported at once."""
    errors = ErrorLog()
    _check_frames(pred, resolve, source, path, errors)
    errors.raise_if_any()


def _check_frames(
    pred: Predicate, resolve: FrameResolver, source: str, path: str, errors: ErrorLog
) -> None:
    if isinstance(pred, PluginPredicate):
        pred = errors.call(pred.resolved)
        if pred is None:
            return
    if isinstance(pred, All):
        for i, part in enumerate(pred.parts):
            _check_frames(part, resolve, source, f"{path}.all[{i}]", errors)
        return
    for key in pred.frame_keys:
        errors.call(resolve.checked, getattr(pred, key), source, f"{path}.{pred.kind}.{key}")


@register("battery_enough")
@dataclass(frozen=True)
class BatteryEnough(Predicate):
    """Enough battery to reach ``goal`` (thesis Eq. 4.3):
    |x_a - x_goal| · α_dist · α_batt / (s_batt - reserve) < 1 and s_batt > reserve."""

    a: str
    goal: str
    alpha_dist: float
    alpha_batt: float
    reserve: float = 60.0
    extra: str = "battery"
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "goal")

    @classmethod
    def from_section(cls, s: Section) -> BatteryEnough:
        return cls(
            a=s.req("a", str),
            goal=s.req("goal", str),
            alpha_dist=s.req("alpha_dist", non_negative),
            alpha_batt=s.req("alpha_batt", non_negative),
            reserve=s.opt("reserve", 60.0, number),
            extra=s.opt("extra", "battery", str),
        )

    def holds(self, view, frames):
        level = view.extras.get(self.extra, 0.0)
        if level <= self.reserve:
            return False
        d = _distance(frames["a"].pos(view.data), frames["goal"].pos(view.data), "xy")
        return d * self.alpha_dist * self.alpha_batt / (level - self.reserve) < 1.0

    def measure(self, view, frames):
        return {self.extra: view.extras.get(self.extra, float("nan"))}
