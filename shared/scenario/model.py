"""``planner.model``: the planner's own copy of the model (solver options, geoms and object
dynamics of its own, welds of held objects)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from shared.config import (
    Section,
    flag,
    non_negative,
    one_of,
    positive_int,
    vector,
)
from shared.scenario.common import count_of
from shared.scenario.variants import VariantsConfig, read_variants


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


SOLVERS = ("Newton", "CG", "PGS")


CONES = ("pyramidal", "elliptic")


INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")


def read_planning_model(s: Section) -> PlanningModel:
    cfg = PlanningModel(
        solver=s.opt("solver", None, one_of(SOLVERS)),
        iterations=s.opt("iterations", None, positive_int),
        ls_iterations=s.opt("ls_iterations", None, positive_int),
        tolerance=s.opt("tolerance", None, non_negative, "a number >= 0 (0: no early stop)"),
        cone=s.opt("cone", None, one_of(CONES)),
        noslip_iterations=s.opt("noslip_iterations", None, count_of, "an integer >= 0"),
        integrator=s.opt("integrator", None, one_of(INTEGRATORS)),
        condim=s.opt("condim", None, _one_of_ints((1, 3, 4, 6)), "1, 3, 4 or 6"),
        exclude=tuple(s.opt("exclude", (), _body_pairs, "a list of [body, body] pairs")),
        attach=tuple(_attach(a) for a in s.items("attach")),
        objects=_object_models(s.section("objects", required=False)),
        geoms=_geom_models(s.section("geoms", required=False)),
        variants=read_variants(s.section("variants")) if s.has("variants") else None,
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
