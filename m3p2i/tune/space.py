"""The space file: the scenario keys searched (their ranges or choices), the objective's
weights, and reading and writing a key in a scenario's raw mapping."""

from __future__ import annotations

import copy
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.config import ConfigError, Section, load_yaml, number, positive_int

DECIMALS = 4  # significant digits of a proposed float: what runs is what the overlay says


MISSING = object()


_SCALAR = (type(None), bool, int, float, str)


_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*(\.[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*)*")


def key_parts(key: str) -> list[str | int]:
    """``objectives.push.terms[2].weight`` -> ``['objectives', 'push', 'terms', 2, 'weight']``."""
    return [int(p) if p.isdigit() else p for p in re.findall(r"[^.\[\]]+", key)]


@dataclass(frozen=True)
class Param:
    """One searched scenario key: a float or int range (``log``: sampled on a log scale;
    ``step``: a grid), or a list of choices (any YAML values)."""

    key: str  # dotted path into the scenario; [i] indexes a list
    kind: str  # float | int | choice
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None
    choices: tuple = ()

    def distribution(self):
        """The Optuna distribution; non-scalar choices (lists, mappings) travel as JSON."""
        from optuna.distributions import (
            CategoricalDistribution,
            FloatDistribution,
            IntDistribution,
        )

        if self.kind == "choice":
            return CategoricalDistribution(self._encoded())
        if self.kind == "int":
            return IntDistribution(int(self.low), int(self.high), log=self.log, step=self.step or 1)
        return FloatDistribution(self.low, self.high, log=self.log, step=self.step)

    def _encoded(self) -> list:
        if all(isinstance(c, _SCALAR) for c in self.choices):
            return list(self.choices)
        return [json.dumps(c) for c in self.choices]

    def value(self, proposed: Any) -> Any:
        """The scenario value of an Optuna parameter: a float rounded to :data:`DECIMALS`
        significant digits, an int, or the choice."""
        if self.kind == "choice":
            return self.choices[self._encoded().index(proposed)]
        if self.kind == "int":
            return int(proposed)
        if self.step is not None:
            return float(round(proposed / self.step) * self.step)
        return float(f"{proposed:.{DECIMALS}g}")

    def encode(self, value: Any) -> Any:
        """A scenario value as an Optuna parameter; ``MISSING`` when it is outside the space."""
        if self.kind == "choice":
            return self._encoded()[self.choices.index(value)] if value in self.choices else MISSING
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return MISSING
        if not self.low <= value <= self.high or (self.kind == "int" and value != int(value)):
            return MISSING
        return int(value) if self.kind == "int" else float(value)

    def ends(self) -> tuple[Any, Any]:
        """The low and high end (first and last choice): the values the loader checks."""
        if self.kind == "choice":
            return self.choices[0], self.choices[-1]
        cast = int if self.kind == "int" else float
        return cast(self.low), cast(self.high)

    def describe(self) -> str:
        if self.kind == "choice":
            return "one of " + ", ".join(json.dumps(c) for c in self.choices)
        scale = ", log scale" if self.log else ""
        step = f", step {self.step:g}" if self.step is not None else ""
        return f"{self.kind} in [{self.low:g}, {self.high:g}]{scale}{step}"


# metric -> what a weight multiplies (docs/tune.md, "The objective")
METRICS = {
    "success": "the success rate (0-1)",
    "time": "mean simulated time to success over successful trials, as a fraction of the "
    "episode's max_time (1 when none succeeded)",
    "position_error": "mean final position error [m]",
    "orientation_error": "mean final orientation error [rad]",
    "collisions": "mean collisions per trial",
}


DEFAULT_WEIGHTS = {
    "success": 1.0,
    "time": -0.01,
    "position_error": -0.01,
    "orientation_error": 0.0,
    "collisions": 0.0,
}


@dataclass(frozen=True)
class Objective:
    """Maximised: ``sum(weight * metric)`` over :data:`METRICS`. The default weights rank by
    success first (a time or an error term moves the score by at most 0.01 per unit, less than
    one seed's success among fewer than 100), then time, then position error."""

    weights: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))

    def formula(self) -> str:
        return " ".join(
            f"{'+' if w >= 0 else '-'} {abs(w):g}·{m}" for m, w in self.weights.items() if w
        ).lstrip("+ ")


@dataclass(frozen=True)
class Space:
    source: str
    params: tuple[Param, ...]
    objective: Objective = field(default_factory=Objective)
    startup_trials: int | None = None  # random proposals before TPE; None: see startup()
    prune: bool = True
    hash: str = ""

    def distributions(self) -> dict:
        return {p.key: p.distribution() for p in self.params}

    def startup(self, trials: int) -> int:
        """TPE's random proposals before it models the history: the file's, else a third of
        the budget (between 2 and 10)."""
        return self.startup_trials or max(2, min(10, trials // 3))


def load_space(path: str | Path) -> Space:
    """Read a space file strictly: errors name the file, the key and the value."""
    path = Path(path)
    data = load_yaml(path)
    top = Section(data, str(path))
    raw_params = top.req("params", dict, "a mapping of scenario keys to ranges or choices")
    if not raw_params:
        raise top.error("params", "needs at least one key", raw_params)
    params = tuple(_param(key, spec, str(path)) for key, spec in raw_params.items())
    obj = top.section("objective", required=False)
    weights = dict(DEFAULT_WEIGHTS)
    for metric in METRICS:
        weights[metric] = obj.opt(metric, weights[metric], number, "a weight (a number)")
    obj.done()
    space = Space(
        source=str(path),
        params=params,
        objective=Objective(weights),
        startup_trials=top.opt("startup_trials", None, positive_int),
        prune=top.opt("prune", True, bool),
        hash=hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[
            :16
        ],
    )
    top.done()
    return space


def _param(key: Any, spec: Any, source: str) -> Param:
    where = f"params.{key}"
    if not isinstance(key, str) or not _KEY.fullmatch(key):
        raise ConfigError(
            source,
            where,
            "not a scenario key",
            key,
            "a dotted path, e.g. planner.samples or objectives.push.terms[1].weight",
        )
    s = Section(spec, source, where)
    if s.has("choices"):
        choices = s.req("choices", list, "a non-empty list of values")
        if not choices:
            raise s.error("choices", "needs at least one value", choices)
        s.done()
        return Param(key, "choice", choices=tuple(choices))
    low = s.req("low", number, "a number")
    high = s.req("high", number, "a number above low")
    ints = all(
        isinstance(s.data[k], int) and not isinstance(s.data[k], bool) for k in ("low", "high")
    )
    kind = s.opt("type", "int" if ints else "float", _kind, "int or float")
    log = s.opt("log", False, bool, "true or false")
    step = s.opt("step", None, _positive, "a number > 0")
    s.done()
    if not low < high:
        raise s.error("high", "must be above low", high, f"a number above {low:g}")
    if kind == "int" and (low != int(low) or high != int(high)):
        raise s.error("low", "an int range needs whole ends", [low, high], "whole numbers")
    if log and low <= 0:
        raise s.error("low", "a log scale needs a positive low end", low, "a number > 0")
    if log and step is not None:
        raise s.error("step", "a log scale has no step", step, "either log or step")
    return Param(key, kind, low, high, log, step)


def _kind(value: Any) -> str:
    if value not in ("int", "float"):
        raise ValueError("must be int or float")
    return value


def _positive(value: Any) -> float:
    v = number(value)
    if v <= 0:
        raise ValueError("must be > 0")
    return v


def get_key(raw: Any, key: str) -> Any:
    """The value at ``key`` in a scenario mapping; ``MISSING`` when any part is absent."""
    node = raw
    for part in key_parts(key):
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                return MISSING
        elif not isinstance(node, dict) or part not in node:
            return MISSING
        node = node[part]
    return node


def set_key(raw: dict, key: str, value: Any, source: str) -> None:
    """Set ``key`` in the scenario mapping ``raw`` in place; missing mappings on the way are
    created (the loader then says whether it knows the key); a list index must exist."""
    parts = key_parts(key)
    node: Any = raw
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        here = ".".join(str(p) for p in parts[: i + 1])
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                size = len(node) if isinstance(node, list) else "not a list"
                raise ConfigError(
                    source,
                    f"params.{key}",
                    f"the scenario has no item {part} at {here}",
                    size,
                    "an index into a list the scenario has",
                )
        elif not isinstance(node, dict):
            raise ConfigError(
                source, f"params.{key}", f"{here} is not inside a mapping", node, "a key path"
            )
        elif not last and node.get(part) is None:
            node[part] = {}
        if last:
            node[part] = copy.deepcopy(value)
        else:
            node = node[part]
