"""The ``episode`` and ``metrics`` sections: the time limit, the success test and what the
summary measures."""

from __future__ import annotations

from dataclasses import dataclass

from shared.config import (
    ErrorLog,
    Section,
    non_negative,
    one_of,
    positive,
    string_list,
    vector,
)
from shared.geometry import AXES
from shared.predicates import Predicate, parse_predicate


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
    """What ``server.evaluation.metrics`` measures per episode (``metrics:``; docs/evaluation.md). A
    metric left as None is not measured."""

    position: FramePairConfig | None = None
    orientation: FramePairConfig | None = None
    collisions: CollisionMetricConfig | None = None


def read_episode(s: Section, errors: ErrorLog) -> EpisodeConfig:
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


def read_metrics(s: Section, episode: EpisodeConfig) -> MetricsConfig:
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
