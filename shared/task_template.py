"""Action templates for the active-inference task planner, read strictly from YAML.

An action template (paper Sec. II.B) describes the symbolic world as independent *state factors*,
each a set of mutually exclusive states, the actions that change one factor, their preconditions,
and the goal. The user never writes a matrix: the planner derives the transition matrices B, the
preferences C, the prior D and the habits E from this description (docs/action_templates.md).

Schema (the ``task`` section of a scenario file)::

    task:
      defaults: {kappa_d: 1.0, idle_habit: 1.01, habit: 1.0}   # optional, these are the defaults
      factors:                     # at least one; YAML order is kept and is the search order
        isAt:
          states: [at_goal, not_at_goal]    # at least two, unique, no '.'
          kappa_d: 1.0                      # optional: belief learning rate of this factor
          actions:                          # optional: a factor may only be observed
            move_to:
              effect: {set: at_goal}        # or {map: {from_state: to_state, ...}}
              preconditions: [battery_ok]   # optional; 'factor.state' where a name is ambiguous
              habit: 1.0                    # optional: prior preference E among tied actions
        battery:
          states: [battery_ok, battery_not_enough]
          actions:
            go_recharge: {effect: {set: battery_ok}, preconditions: [battery_not_enough]}
      goals: {isAt: at_goal}       # factor: state, at least one; success when all hold

Every factor also gets an implicit ``idle`` action (identity transition, no preconditions,
habit ``idle_habit``); the name is reserved. ``idle_habit`` must exceed every action's habit, so
that an action that would change nothing never beats idling.

Effects: ``{set: s}`` takes every state of the factor to ``s`` (a postcondition);
``{map: {a: b}}`` takes ``a`` to ``b`` and leaves unlisted states where they are. ``identity`` is
recognised only to be rejected: an action that can never change its factor is a template error.

Every error is a :class:`shared.config.ConfigError` naming the file, the key path, the bad value
and what was expected, e.g. ``battery.yaml: task.factors.isAt.actions.move_to.preconditions[0]:
unknown state (got 'battery_okk'; expected one of: at_goal, battery_not_enough, battery_ok, ...)``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

from shared.config import ConfigError, Section, non_negative, positive

IDLE = "idle"
DEFAULT_KAPPA_D = 1.0
DEFAULT_IDLE_HABIT = 1.01
DEFAULT_HABIT = 1.0


@dataclass(frozen=True)
class StateRef:
    """One state of one factor, written ``factor.state``."""

    factor: str
    state: str

    def __str__(self) -> str:
        return f"{self.factor}.{self.state}"


@dataclass(frozen=True)
class Effect:
    """Where an action takes each state of its factor; states not listed in ``moves`` stay."""

    kind: Literal["set", "map"]
    moves: tuple[tuple[str, str], ...]  # (from_state, to_state), in YAML order

    def target(self, state: str) -> str:
        return dict(self.moves).get(state, state)


@dataclass(frozen=True)
class ActionTemplate:
    name: str
    factor: str
    effect: Effect
    preconditions: tuple[StateRef, ...]
    habit: float


@dataclass(frozen=True)
class FactorTemplate:
    name: str
    states: tuple[str, ...]
    actions: tuple[ActionTemplate, ...]  # user actions only; idle is implicit
    kappa_d: float


@dataclass(frozen=True)
class TaskTemplate:
    factors: tuple[FactorTemplate, ...]
    goals: tuple[StateRef, ...]
    idle_habit: float

    def factor(self, name: str) -> FactorTemplate:
        for f in self.factors:
            if f.name == name:
                return f
        raise KeyError(name)

    def actions(self) -> Iterator[ActionTemplate]:
        """All user actions, factor by factor in template order."""
        for f in self.factors:
            yield from f.actions


def parse_task(section: Section) -> TaskTemplate:
    """Read and validate the ``task`` section of a scenario (schema in the module docstring)."""
    defaults = section.section("defaults", required=False)
    kappa_default = defaults.opt("kappa_d", DEFAULT_KAPPA_D, non_negative, "a number >= 0")
    idle_habit = defaults.opt("idle_habit", DEFAULT_IDLE_HABIT, positive, "a number > 0")
    habit_default = defaults.opt("habit", DEFAULT_HABIT, positive, "a number > 0")
    defaults.done()
    if not habit_default < idle_habit:
        raise defaults.error(
            "habit",
            f"must be below idle_habit ({idle_habit})",
            habit_default,
            "a habit below idle_habit, so idle wins ties",
        )

    factors_sec = section.section("factors")
    if not factors_sec.data:
        raise ConfigError(
            section.source,
            factors_sec.path,
            "needs at least one factor",
            expected="factor_name: {states: [...], actions: {...}}",
        )
    # Preconditions may name states of any factor, so every factor's states are read first.
    factor_secs: dict[str, Section] = {}
    states: dict[str, tuple[str, ...]] = {}
    for name in factors_sec.data:
        _check_name(factors_sec, name, name, "factor")
        factor_secs[name] = factors_sec.section(name)
        states[name] = _parse_states(factor_secs[name])
    factors_sec.done()

    resolver = _StateResolver(states)
    seen_actions: dict[str, str] = {}
    factors = []
    for name, fsec in factor_secs.items():
        kappa_d = fsec.opt("kappa_d", kappa_default, non_negative, "a number >= 0")
        actions_sec = fsec.section("actions", required=False)
        actions = []
        for action in actions_sec.data:
            _check_name(actions_sec, action, action, "action")
            if action == IDLE:
                raise actions_sec.error(
                    action, "'idle' is implicit in every factor", action, "another action name"
                )
            if action in seen_actions:
                raise actions_sec.error(
                    action,
                    f"duplicate action, already in factor {seen_actions[action]!r}",
                    action,
                    "unique action names",
                )
            seen_actions[action] = name
            actions.append(
                _parse_action(
                    actions_sec.section(action),
                    action,
                    name,
                    states[name],
                    resolver,
                    habit_default,
                    idle_habit,
                )
            )
        actions_sec.done()
        fsec.done()
        factors.append(FactorTemplate(name, states[name], tuple(actions), kappa_d))

    goals = _parse_goals(section.section("goals"), states)
    section.done()
    return TaskTemplate(tuple(factors), goals, idle_habit)


def _check_name(sec: Section, key: Any, value: Any, what: str) -> None:
    if not isinstance(value, str) or not value or "." in value:
        raise sec.error(
            str(key),
            f"bad {what} name",
            value,
            "a non-empty string without '.' (quote yes/no/on/off/numbers)",
        )


def _parse_states(fsec: Section) -> tuple[str, ...]:
    names = tuple(fsec.req("states", list, "a list of at least two state names"))
    for i, s in enumerate(names):
        _check_name(fsec, f"states[{i}]", s, "state")
    if len(names) < 2:
        raise fsec.error(
            "states", "needs at least two states", list(names), "a list of at least two state names"
        )
    if len(set(names)) != len(names):
        dup = next(s for i, s in enumerate(names) if s in names[:i])
        raise fsec.error("states", f"duplicate state {dup!r}", list(names), "unique state names")
    return names


class _StateResolver:
    """Turns 'state' or 'factor.state' into a StateRef, with errors naming the candidates."""

    def __init__(self, states: dict[str, tuple[str, ...]]):
        self.states = states
        self.owners: dict[str, list[str]] = {}
        for factor, names in states.items():
            for s in names:
                self.owners.setdefault(s, []).append(factor)

    def resolve(self, text: str, source: str, path: str) -> StateRef:
        if "." in text:
            factor, _, state = text.partition(".")
            if factor not in self.states:
                raise ConfigError(
                    source, path, "unknown factor", text, f"one of: {', '.join(self.states)}"
                )
            if state not in self.states[factor]:
                raise ConfigError(
                    source,
                    path,
                    f"unknown state of factor {factor!r}",
                    text,
                    f"one of: {', '.join(self.states[factor])}",
                )
            return StateRef(factor, state)
        owners = self.owners.get(text, [])
        if not owners:
            known = sorted(self.owners)
            raise ConfigError(source, path, "unknown state", text, f"one of: {', '.join(known)}")
        if len(owners) > 1:
            options = ", ".join(f"{f}.{text}" for f in owners)
            raise ConfigError(source, path, "ambiguous state name", text, f"one of: {options}")
        return StateRef(owners[0], text)


def _parse_action(
    asec: Section,
    name: str,
    factor: str,
    states: tuple[str, ...],
    resolver: _StateResolver,
    habit_default: float,
    idle_habit: float,
) -> ActionTemplate:
    effect = _parse_effect(asec, factor, states)
    raw = asec.opt("preconditions", [], list, "a list of state names")
    preconditions: list[StateRef] = []
    for i, text in enumerate(raw):
        path = f"{asec.key_path('preconditions')}[{i}]"
        if not isinstance(text, str):
            raise ConfigError(
                asec.source,
                path,
                "bad state name",
                text,
                "a state name as a string (quote yes/no/on/off/numbers)",
            )
        ref = resolver.resolve(text, asec.source, path)
        clash = next((p for p in preconditions if p.factor == ref.factor), None)
        if clash == ref:
            raise ConfigError(asec.source, path, "duplicate precondition", text, "each state once")
        if clash is not None:
            raise ConfigError(
                asec.source,
                path,
                f"contradicts precondition {clash}: a factor is in one state at a time",
                text,
                "one state per factor",
            )
        preconditions.append(ref)
    habit = asec.opt("habit", habit_default, positive, "a number > 0")
    if not habit < idle_habit:
        raise asec.error(
            "habit",
            f"must be below idle_habit ({idle_habit})",
            habit,
            "a habit below idle_habit, so idle wins ties",
        )
    asec.done()
    return ActionTemplate(name, factor, effect, tuple(preconditions), habit)


def _parse_effect(asec: Section, factor: str, states: tuple[str, ...]) -> Effect:
    expected = "{set: state}, or {map: {from_state: to_state}}"
    raw = asec.req("effect", object, expected)
    if raw == "identity":
        raise asec.error(
            "effect", "an identity effect never changes the state (idle is implicit)", raw, expected
        )
    if not isinstance(raw, dict) or len(raw) != 1 or next(iter(raw)) not in ("set", "map"):
        raise asec.error("effect", "must have exactly one of 'set' or 'map'", raw, expected)
    esec = Section(raw, asec.source, asec.key_path("effect"))
    known = f"a state of factor {factor!r}: {', '.join(states)}"
    if esec.has("set"):
        target = esec.req("set", str, known)
        if target not in states:
            raise esec.error("set", f"unknown state of factor {factor!r}", target, known)
        return Effect("set", tuple((s, target) for s in states))
    msec = esec.section("map")
    moves = []
    for src in msec.data:
        if src not in states:
            raise msec.error(str(src), f"unknown state of factor {factor!r}", src, known)
        dst = msec.req(src, str, known)
        if dst not in states:
            raise msec.error(src, f"unknown state of factor {factor!r}", dst, known)
        if dst != src:
            moves.append((src, dst))
    if not moves:
        raise asec.error(
            "effect",
            "a map that moves no state never changes anything",
            raw,
            "at least one from_state: to_state with different states",
        )
    return Effect("map", tuple(moves))


def _parse_goals(gsec: Section, states: dict[str, tuple[str, ...]]) -> tuple[StateRef, ...]:
    if not gsec.data:
        raise ConfigError(
            gsec.source, gsec.path, "needs at least one goal", expected="factor: state"
        )
    goals = []
    for factor in gsec.data:
        if factor not in states:
            raise gsec.error(str(factor), "unknown factor", factor, f"one of: {', '.join(states)}")
        state = gsec.req(factor, str, f"a state of factor {factor!r}")
        if state not in states[factor]:
            raise gsec.error(
                factor,
                f"unknown state of factor {factor!r}",
                state,
                f"one of: {', '.join(states[factor])}",
            )
        goals.append(StateRef(factor, state))
    gsec.done()
    return tuple(goals)
