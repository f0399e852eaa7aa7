"""The ``objectives`` and ``include`` sections: each objective's weighted cost terms, and
objective files shared between scenarios (``extends``)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.config import (
    ConfigError,
    ErrorLog,
    Section,
    load_yaml,
    number,
    one_of,
    string_list,
)
from shared.config_files import find


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


def find_objectives(name_or_path: str | os.PathLike) -> Path:
    """A path as given, else ``NAME.yaml`` in the user's objectives folders, then the shipped
    ones."""
    return find(name_or_path, "objectives")


def read_includes(top: Section, errors: ErrorLog) -> tuple[dict[str, ObjectiveConfig], list[dict]]:
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
            lambda s=s: read_objectives(s.section("objectives"), errors, library), default={}
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


def read_objectives(
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
