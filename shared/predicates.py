"""Logical predicates over the continuous world state, named in YAML.

They serve twice: the server's success test (all of ``episode.success`` must hold) and the
planner's symbolic observers (paper Eqs. 13, 23-26; thesis Eq. 4.3), which turn a predicate's
truth into a discrete observation for active inference. Each predicate is a small frozen
dataclass built from its YAML parameters, validated at scenario load; frame names are checked
against the compiled model by :meth:`Predicate.bind`.

Add one with ``@register("name")`` on a class with ``from_section`` and ``holds``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np

from shared.config import ConfigError, Section, non_negative, number, one_of
from shared.frames import Frame, FrameResolver

PREDICATES: dict[str, type[Predicate]] = {}


def register(name: str) -> Callable[[type], type]:
    def wrap(cls: type) -> type:
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

    def frames(self) -> list[str]:
        return [getattr(self, k) for k in self.frame_keys]

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
    return one_of(["xy", "xyz"])(value)


def _distance(a: np.ndarray, b: np.ndarray, axes: str) -> float:
    d = a - b
    return float(np.linalg.norm(d[:2] if axes == "xy" else d))


@register("near")
@dataclass(frozen=True)
class Near(Predicate):
    """|x_a - x_b| <= within (paper Eq. 13, Eq. 23); ``axes: xy`` ignores height."""
    a: str
    b: str
    within: float
    axes: str = "xyz"
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "b")

    @classmethod
    def from_section(cls, s: Section) -> Near:
        return cls(a=s.req("a", str), b=s.req("b", str), within=s.req("within", non_negative),
                   axes=s.opt("axes", "xyz", _axes))

    def distance(self, view, frames) -> float:
        return _distance(frames["a"].pos(view.data), frames["b"].pos(view.data), self.axes)

    def holds(self, view, frames):
        return self.distance(view, frames) <= self.within

    def measure(self, view, frames):
        return {f"distance {self.a}-{self.b}": self.distance(view, frames)}


@register("far")
@dataclass(frozen=True)
class Far(Near):
    """|x_a - x_b| > beyond: the negation of ``near`` for templates that need it by name."""

    @classmethod
    def from_section(cls, s: Section) -> Far:
        return cls(a=s.req("a", str), b=s.req("b", str), within=s.req("beyond", non_negative),
                   axes=s.opt("axes", "xyz", _axes))

    def holds(self, view, frames):
        return self.distance(view, frames) > self.within


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


def parse_predicate(s: Section) -> Predicate:
    """``{near: {a: robot, b: goal, within: 0.1}}`` -> a Predicate (one key: the predicate name)."""
    if len(s.data) != 1:
        raise ConfigError(s.source, s.path, "a predicate is a mapping with exactly one key",
                          sorted(s.data), f"one of: {', '.join(sorted(PREDICATES))}")
    (name,) = s.data
    if name not in PREDICATES:
        raise s.error(name, "unknown predicate", name, f"one of: {', '.join(sorted(PREDICATES))}")
    params = s.section(name)
    pred = PREDICATES[name].from_section(params)
    params.done()
    s.done()
    return pred


def check_frames(pred: Predicate, resolve: FrameResolver, source: str, path: str) -> None:
    """Load-time check that every frame a predicate names exists in the model."""
    for key in pred.frame_keys:
        name = getattr(pred, key)
        try:
            resolve(name)
        except KeyError as exc:
            raise ConfigError(source, f"{path}.{pred.kind}.{key}", str(exc.args[0]), name,
                              f"one of: {', '.join(resolve.names())}") from None


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
        return cls(a=s.req("a", str), goal=s.req("goal", str),
                   alpha_dist=s.req("alpha_dist", non_negative),
                   alpha_batt=s.req("alpha_batt", non_negative),
                   reserve=s.opt("reserve", 60.0, number), extra=s.opt("extra", "battery", str))

    def holds(self, view, frames):
        level = view.extras.get(self.extra, 0.0)
        if level <= self.reserve:
            return False
        d = _distance(frames["a"].pos(view.data), frames["goal"].pos(view.data), "xy")
        return d * self.alpha_dist * self.alpha_batt / (level - self.reserve) < 1.0

    def measure(self, view, frames):
        return {self.extra: view.extras.get(self.extra, float("nan"))}
