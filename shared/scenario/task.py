"""The task layer's sections: ``observers`` of the template's factors and ``plan`` (the
objective that executes each action)."""

from __future__ import annotations

from dataclasses import dataclass

from shared.config import (
    ErrorLog,
    Section,
    one_of,
)
from shared.predicates import Predicate, parse_predicate
from shared.task_template import FactorTemplate, TaskTemplate


@dataclass(frozen=True)
class ObserverConfig:
    """Symbolic observer of one task factor: the first rule whose predicate holds gives the
    observed state; ``default`` when none holds."""

    rules: tuple[tuple[str, Predicate], ...]
    default: str


def read_observers(
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
    """One task factor's observer (see :func:`read_observers`)."""
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


def read_plan(s: Section, task: TaskTemplate, objectives: dict) -> dict[str, str]:
    """The plan interface (paper II.D): every task action -> the objective that executes it."""
    out = {}
    for action in task.actions():
        out[action.name] = s.req(
            action.name, one_of(objectives), f"an objective: {', '.join(objectives)}"
        )
    s.done()
    return out
