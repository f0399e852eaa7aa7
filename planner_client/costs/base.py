"""The cost-term interface: a named, vectorised function of a rollout batch.

A term is built once from its YAML parameters (validated then, errors naming file and key path),
declares the sensors it reads, and maps a :class:`RolloutBatch` to per-step costs ``[S, T]``.
Weights and running/terminal masks are applied by :class:`~planner_client.costs.Objective`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, ClassVar, Protocol

import torch

from planner_client.sensors import SensorColumns, SensorRequest
from shared.config import Section, string_list
from shared.frames import FrameResolver
from shared.robots import RobotSpec

if TYPE_CHECKING:
    from planner_client.perception.field import DistanceField

TERMS: dict[str, type[CostTerm]] = {}


def register(name: str) -> Callable[[type], type]:
    """Class decorator: make a term available to YAML as ``term: name``. A name is registered
    once: a second term of the same name (a plugin's, docs/cost_terms.md) is refused, naming
    both classes."""

    def wrap(cls: type) -> type:
        if name in TERMS and TERMS[name] is not cls:
            old = TERMS[name]
            raise ValueError(
                f"cost term {name!r} registered twice: by {old.__module__}.{old.__qualname__} "
                f"and by {cls.__module__}.{cls.__qualname__}; give the new term another name"
            )
        cls.name = name
        TERMS[name] = cls
        return cls

    return wrap


@dataclass
class RolloutBatch:
    """What terms read: ``sensordata [S, T, nsensordata]`` and ``controls [S, T, nu]``."""

    sensordata: torch.Tensor
    controls: torch.Tensor
    columns: SensorColumns
    dt: float

    def get(self, req: SensorRequest) -> torch.Tensor:
        """``[S, T, dim]`` values of one requested sensor."""
        return self.columns.take(self.sensordata, req)


@dataclass(frozen=True)
class Norm:
    """One Euclidean norm of an affine map of a step's sensor values, ‖z‖ with
    z_i = bias_i + Σ c · value (the ``(request, index, c)`` of ``components[i]``): a distance
    is ``x_a - x_b - offset`` along its axes, a contact force its three values.

    A term that is a sum of such norms (:meth:`CostTerm.norms`) lets an objective compute it
    together with its other norm terms (:mod:`planner_client.costs.norms`). ``floor`` bounds the
    squared norm from below before the root (:func:`~planner_client.costs.helpers.sparse_norm`).
    """

    components: tuple[tuple[float, tuple[tuple[SensorRequest, int, float], ...]], ...]
    floor: float = 0.0


@dataclass(frozen=True)
class JointInfo:
    """A robot joint (hinge or slide) as terms see it: its range (None when unlimited), whether
    it is a hinge (radians) or a slide (metres), and its position in the scenario's start pose."""

    range: tuple[float, float] | None
    hinge: bool
    start: float


class FieldSource(Protocol):
    """Where terms and the guide read the planner's map: :meth:`latest` is the newest signed
    distance field (:class:`~planner_client.perception.field.DistanceField`), or None while
    there is none. Read at every evaluation: the map is updated beside the planner, between
    iterations, never during one."""

    def latest(self) -> DistanceField | None: ...


class FieldSlot:
    """The :class:`FieldSource` a planning problem owns from the start
    (``PlanningProblem.field_source``), before its map exists: :meth:`latest` reads the source
    :meth:`connect` gave it (the map updater), None while there is none."""

    def __init__(self) -> None:
        self._source: FieldSource | None = None

    def connect(self, source: FieldSource | None) -> None:
        """Read ``source`` from now on (None: no map)."""
        self._source = source

    def latest(self) -> DistanceField | None:
        return self._source.latest() if self._source is not None else None


@dataclass
class TermContext:
    """What a term may check its parameters against at load time."""

    source: str
    resolve: FrameResolver
    obstacles: list[str]
    actuators: list[str]
    joints: dict[str, JointInfo] = field(default_factory=dict)  # the robot's, in qpos order
    guide: object | None = None  # the scenario's GuideState (planner_client.guide), if any
    robot: RobotSpec | None = None  # the scenario's robot: its collision spheres
    field_source: FieldSource | None = None  # the planner's map, for terms that read it

    def frame(self, s: Section, key: str, default: str | None = None) -> str:
        """A frame name parameter, checked to exist in the model."""
        name = s.req(key, str) if default is None else s.opt(key, default, str)
        self.resolve.checked(name, s.source, s.key_path(key))
        return name

    def bodies(self, s: Section, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
        """A list of body names (``obstacles``), each checked to exist in the model."""
        names = s.opt(key, default, string_list, "a list of body names")
        for i, name in enumerate(names):
            self.resolve.checked(name, s.source, f"{s.key_path(key)}[{i}]")
        return names

    def channel(self, name: str, s: Section, key: str) -> int:
        """The control channel of an actuator name, or an error listing the actuators: the one
        place an actuator name from YAML is checked."""
        if name not in self.actuators:
            raise s.error(key, "unknown actuator", name, f"one of: {', '.join(self.actuators)}")
        return self.actuators.index(name)

    def channels(self, s: Section, key: str, names: tuple[str, ...]) -> tuple[int, ...]:
        """The control channels (indices in the last axis of ``batch.controls``) of actuator
        ``names``, the list parameter ``key``: each checked by :meth:`channel`."""
        return tuple(self.channel(n, s, key) for n in names)


class CostTerm(ABC):
    """Base class of cost terms; subclasses are registered with :func:`register`."""

    name: ClassVar[str]

    @classmethod
    @abstractmethod
    def from_params(cls, s: Section, ctx: TermContext) -> CostTerm:
        """Build from YAML parameters (``s`` holds them, minus term/weight/when)."""

    @abstractmethod
    def sensors(self) -> list[SensorRequest]:
        """Sensor quantities this term reads from rollouts."""

    @cached_property
    def requests(self) -> list[SensorRequest]:
        """:meth:`sensors`, built once: the hot loop reads these every iteration."""
        return self.sensors()

    @cached_property
    def key(self) -> str:
        """Equal for terms that compute the same values: a term is a pure function of the batch
        and its parameters, which a dataclass term's repr lists in full (class name included).
        Objectives evaluate a term once per iteration by it, however many times it is listed."""
        return repr(self)

    @abstractmethod
    def __call__(self, batch: RolloutBatch) -> torch.Tensor:
        """Unweighted per-step cost ``[S, T]``, of the dtype of ``batch.sensordata`` on its
        device (checked once at start-up: :func:`~planner_client.problem.check_terms`)."""

    def norms(self) -> list[Norm] | None:
        """This term as a sum of Euclidean norms of affine maps of the sensors (the same values
        as :meth:`__call__` to rounding), or ``None`` when it is not one: the default."""
        return None
