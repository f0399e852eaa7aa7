"""``m3p2i tune``: a scenario's parameters found by a search over bench trials (thesis Sec. 6.3:
"an algorithm that can automatically tune these hyperparameters"), not by hand.

A **space file** (``configs/tune/*.yaml``, docs/tune.md) names scenario keys and their ranges or
choices, and the objective's weights. Every value of the space is read by the scenario loader
before any trial (the loader's message for a misspelt key or a value out of its range), and the
space's two corners (every key at its low end, every key at its high end) by both processes'
``--check``. Optuna's TPE proposes a parameter set per study trial; the bench runs it on the
training seeds (warm process pairs, or Ray tasks) and appends its rows to ``results.csv``; the
objective scores them. Trial 0 is the original's values when the scenario sets every key inside
the space, so a study never reports a set worse on its own seeds than what it started from.

Deterministic for its seed: the sampler of the study's n-th finished trial is seeded from
(``--sampler-seed``, n) and lock-step episodes repeat on one machine, so two studies with the
same seed propose the same sets. Resumable: the study lives in ``OUT/study.db`` (SQLite); a rerun
marks an interrupted trial failed, proposes it again (the same set, from the same seed and
history) and reuses the seeds it had finished (``results.csv`` keeps them by scenario hash).

The best set is written as ``OUT/overlay.yaml`` (``base:`` the original plus the tuned keys) and
evaluated beside the original on held-out seeds; ``OUT/report.md`` has the history, the
parameter importances, the best trial's seeds and that evaluation with Wilson intervals.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from m3p2i import bench as B
from m3p2i.bench_report import seed_ranges, wilson
from m3p2i.provenance import machine, versions
from shared.config import ConfigError, Section, load_yaml, number, positive_int
from shared.config_files import entries
from shared.evaluation.metrics import MetricsEvaluator
from shared.scenario import Scenario, find_scenario, load_scenario, parse_scenario

STUDY = "tune"  # the study's name in OUT/study.db
DECIMALS = 4  # significant digits of a proposed float: what runs is what the overlay says
_MISSING = object()
_SCALAR = (type(None), bool, int, float, str)

# ------------------------------------------------------------------------------- search space

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
        """A scenario value as an Optuna parameter; ``_MISSING`` when it is outside the space."""
        if self.kind == "choice":
            return self._encoded()[self.choices.index(value)] if value in self.choices else _MISSING
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return _MISSING
        if not self.low <= value <= self.high or (self.kind == "int" and value != int(value)):
            return _MISSING
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


# ------------------------------------------------------------------------------ scenario keys


def get_key(raw: Any, key: str) -> Any:
    """The value at ``key`` in a scenario mapping; ``_MISSING`` when any part is absent."""
    node = raw
    for part in key_parts(key):
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                return _MISSING
        elif not isinstance(node, dict) or part not in node:
            return _MISSING
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


# -------------------------------------------------------------------------------------- target


@dataclass(frozen=True)
class Target:
    """What is tuned: a bench case (its mode, faults, plan rate) and its scenario."""

    case: B.BenchCase
    scenario: Scenario
    base: str  # what the overlay's base: names: a scenario name, or an absolute path
    timeout: float  # wall-clock seconds per trial
    label: str  # for the report


def resolve_target(spec: str, timeout: float | None = None) -> Target:
    """``BENCH:CASE`` (a case of a bench file), a scenario (name or path; a lock-step case of its
    own), else a case name of one of the bench files (``m3p2i list bench``)."""
    bench, sep, case = spec.rpartition(":")
    if sep and bench:
        return _case_target(B.load_bench(bench), case, timeout)
    try:
        path = find_scenario(spec)
    except ConfigError:
        found = []
        for e in entries("bench"):
            if e.shadowed_by is not None:
                continue
            try:
                cfg = B.load_bench(e.path)
            except ConfigError:
                continue
            if any(c.case == spec for c in cfg.cases):
                found.append(cfg)
        if len(found) != 1:
            why = "no scenario or bench case of this name" if not found else "a case of several"
            raise ConfigError(
                spec,
                "",
                why + (f" bench files ({', '.join(c.source for c in found)})" if found else ""),
                expected="a scenario (m3p2i list), a case name, or BENCH:CASE",
            ) from None
        return _case_target(found[0], spec, timeout)
    scenario = load_scenario(path)
    case = B.BenchCase(case=scenario.name, variant="", scenario=str(path.resolve()), trials=1)
    base = spec if not Path(spec).is_file() else str(path.resolve())
    return Target(case, scenario, base, timeout or 600.0, f"scenario {scenario.name}, lockstep")


def _case_target(cfg: B.BenchConfig, name: str, timeout: float | None) -> Target:
    case = next((c for c in cfg.cases if c.case == name), None)
    if case is None:
        raise ConfigError(
            cfg.source, "cases", "no such case", name, ", ".join(c.case for c in cfg.cases)
        )
    local = Path(cfg.source).parent / case.scenario
    path = local if local.is_file() else find_scenario(case.scenario)
    base = str(path.resolve()) if local.is_file() else case.scenario
    case = dataclasses.replace(case, scenario=str(path.resolve()))
    return Target(
        case,
        load_scenario(path),
        base,
        timeout or cfg.timeout,
        f"case {name} of {cfg.source} ({case.mode_label})",
    )


# ------------------------------------------------------------------------------------ variants


def values_id(values: dict[str, Any]) -> str:
    """A short name for a parameter set: the hash of its values."""
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:8]


def variant_raw(target: Target, space: Space, values: dict[str, Any]) -> dict:
    """The target's scenario mapping with ``values`` set, read by the scenario loader (its
    error names the scenario file, the space file and the values)."""
    raw = copy.deepcopy(target.scenario.raw)
    for key, value in values.items():
        set_key(raw, key, value, space.source)
    raw.setdefault("name", target.scenario.name)
    shown = ", ".join(f"{k}={json.dumps(v)}" for k, v in values.items())
    parse_scenario(raw, f"{target.scenario.source} with {space.source} ({shown})")
    return raw


def write_variant(target: Target, space: Space, values: dict[str, Any], folder: Path) -> Scenario:
    """``variant_raw`` written to ``folder/ID/NAME.yaml`` (both processes load it) and loaded."""
    raw = variant_raw(target, space, values)
    out = folder / values_id(values) / f"{target.scenario.name}.yaml"
    out.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(raw, sort_keys=False)
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)
    return load_scenario(out)


def check_space(
    target: Target,
    space: Space,
    folder: Path,
    process_check: Callable[[str], list[str]] | None = None,
) -> list[str]:
    """Every end of every key read by the scenario loader (raises its ConfigError); then the
    two corners of the space (all keys low, all keys high) checked by ``process_check`` (both
    processes' ``--check``: what only they resolve, MPPI keys and cost-term parameters).
    Returns the processes' messages, empty when the space is sound."""
    for p in space.params:
        for end in p.ends():
            variant_raw(target, space, {p.key: end})
    if process_check is None:
        return []
    corners = [{p.key: p.ends()[i] for p in space.params} for i in (0, 1)]
    messages = []
    for values in corners:
        scenario = write_variant(target, space, values, folder)
        shown = ", ".join(f"{k}={json.dumps(v)}" for k, v in values.items())
        messages += [f"{space.source} ({shown}): {m}" for m in process_check(scenario.source)]
    return messages


def baseline(target: Target, space: Space) -> dict[str, Any] | None:
    """The original's values as Optuna parameters, when the scenario sets every key inside the
    space; else None."""
    out = {}
    for p in space.params:
        v = p.encode(get_key(target.scenario.raw, p.key))
        if v is _MISSING:
            return None
        out[p.key] = v
    return out


def overlay(target: Target, space: Space, values: dict[str, Any]) -> dict:
    """A scenario of ``base:`` the target plus the tuned keys. A key inside a list carries the
    whole list (a base's list is replaced, not merged), with the tuned items set."""
    tuned = variant_raw(target, space, values)
    out: dict = {
        "base": target.base,
        "name": f"{target.scenario.name}_tuned",
        "description": f"{target.scenario.name} with the parameters m3p2i tune found "
        f"({Path(space.source).name})",
    }
    for key in values:
        parts = key_parts(key)
        cut = next((i for i, p in enumerate(parts) if isinstance(p, int)), len(parts))
        head = parts[:cut]
        node = out
        for part in head[:-1]:
            node = node.setdefault(part, {})
        node[head[-1]] = copy.deepcopy(get_key(tuned, ".".join(map(str, head))))
    return out


# --------------------------------------------------------------------------------------- score


@dataclass(frozen=True)
class Score:
    """A parameter set's bench metrics over some seeds."""

    rows: tuple[dict, ...]

    @property
    def trials(self) -> int:
        return len(self.rows)

    @property
    def successes(self) -> int:
        return sum(_won(r) for r in self.rows)

    def failed_seeds(self) -> list[int]:
        return sorted(int(r["seed"]) for r in self.rows if not _won(r))

    def mean(self, metric: str, max_time: float) -> float:
        """:data:`METRICS`' value of ``metric`` over the rows."""
        if metric == "success":
            return self.successes / self.trials
        if metric == "time":
            times = [_num(r.get("time")) for r in self.rows if _won(r)]
            times = [t for t in times if t is not None]
            return sum(times) / len(times) / max_time if times else 1.0
        values = [v for r in self.rows if (v := _num(r.get(metric))) is not None]
        return sum(values) / len(values) if values else 0.0

    def value(self, objective: Objective, max_time: float) -> float:
        return sum(w * self.mean(m, max_time) for m, w in objective.weights.items() if w)

    def best_possible(self, objective: Objective, max_time: float, total: int) -> float | None:
        """The highest value this set can still reach when the seeds left (``total`` in all)
        all succeed at once without an error; None when a weight rewards time or errors (no
        bound then)."""
        if any(w > 0 for m, w in objective.weights.items() if m != "success"):
            return None
        ideal = {"success": "1", "reason": "", "time": "0", "seed": "-1"}
        ideal.update({m: "0" for m in METRICS if m not in ("success", "time")})
        left = total - self.trials
        return Score(self.rows + (ideal,) * left).value(objective, max_time)

    def time_stats(self) -> tuple[float, float] | None:
        times = [t for r in self.rows if _won(r) and (t := _num(r.get("time"))) is not None]
        if not times:
            return None
        mean = sum(times) / len(times)
        return mean, math.sqrt(sum((t - mean) ** 2 for t in times) / len(times))


def _won(row: dict) -> bool:
    return str(row.get("success")) in ("1", "True") and not row.get("reason")


def _num(cell: Any) -> float | None:
    try:
        v = float(cell)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ------------------------------------------------------------------------------------ the study


@dataclass(frozen=True)
class TuneOptions:
    out: Path
    trials: int  # finished (complete or pruned) study trials wanted in all
    seeds: tuple[int, ...]  # training seeds of every trial
    holdout: tuple[int, ...] = ()  # seeds of the final comparison; none tuned on
    sampler_seed: int = 0
    workers: int = 1


# runs bench trials, appending rows to the results file and passing each to on_done; False when
# interrupted. The bench's local pool or its Ray tasks (make_runner), or a test's stand-in.
Runner = Callable[[list[B.Trial], B.ResultsFile, Callable[[dict], None]], bool]


def make_runner(opts: TuneOptions, timeout: float, cluster=None, cpus_per_trial: int = 1) -> Runner:
    """The bench's runner: warm local pairs, or Ray tasks on ``cluster``."""
    bench_opts = B.BenchOptions(out_dir=opts.out, workers=opts.workers, timeout=timeout)

    def run(trials, results, on_done):
        if cluster is not None:
            from m3p2i import bench_ray

            return bench_ray.run_trials(
                trials, bench_opts, results, cluster, cpus_per_trial, on_done
            )
        return B.run_trials(trials, bench_opts, results, on_done)

    return run


class _Hopeless(Exception):
    """Raised from a row callback to stop a trial's remaining seeds (pruned)."""


@dataclass
class TrialOutcome:
    number: int
    values: dict[str, Any]
    score: Score
    state: str  # complete | pruned
    objective: float


@dataclass
class Events:
    """What the study reports as it goes (the CLI's progress bar)."""

    row: Callable[[dict], None] = lambda row: None
    skipped: Callable[[int], None] = lambda n: None  # seeds a pruned trial did not run
    trial: Callable[[TrialOutcome], None] = lambda t: None


def _sampler(seed: int, finished: int, startup: int):
    """TPE seeded from (seed, finished trials): a resumed study proposes what an uninterrupted
    one would."""
    import numpy as np
    import optuna

    s = int(np.random.SeedSequence([seed, finished]).generate_state(1)[0])
    return optuna.samplers.TPESampler(seed=s, n_startup_trials=startup)


def _finished(study) -> list:
    from optuna.trial import TrialState

    return study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED))


def storage_url(out: Path) -> str:
    return f"sqlite:///{(out / 'study.db').resolve()}"


def open_storage(out: Path):
    """``OUT/study.db``; one object per run, since opening one checks the schema (a second)."""
    import optuna

    out.mkdir(parents=True, exist_ok=True)
    return optuna.storages.RDBStorage(storage_url(out))


def open_study(target: Target, space: Space, opts: TuneOptions, storage=None):
    """The study in ``OUT/study.db``, new or resumed; a study of another target, space or
    training seeds there is refused. Trials left running by an interrupted run are marked
    failed (they are proposed again)."""
    import optuna
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = storage or open_storage(opts.out)
    study = optuna.create_study(
        study_name=STUDY,
        storage=storage,
        direction="maximize",
        load_if_exists=True,
        sampler=_sampler(opts.sampler_seed, 0, space.startup(opts.trials)),
    )
    meta = {
        "target": target.label,
        "scenario_hash": target.scenario.hash,
        "space_hash": space.hash,
        "seeds": list(opts.seeds),
        "sampler_seed": opts.sampler_seed,
    }
    known = study.user_attrs
    if not known:
        for k, v in meta.items():
            study.set_user_attr(k, v)
    else:
        for k, v in meta.items():
            if known.get(k) != v:
                raise ConfigError(
                    str(opts.out / "study.db"),
                    k,
                    "holds a study with another " + k.replace("_", " "),
                    known.get(k),
                    f"{v!r} (resume with the same target, space, seeds and sampler seed, or "
                    "choose another --out)",
                )
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study.tell(t.number, state=TrialState.FAIL)
    return study


@dataclass(frozen=True)
class _Limit:
    """When a trial is hopeless: even with every seed left succeeding at once without an error,
    it could not beat the best complete trial (``best``; None: nothing to beat yet)."""

    space: Space
    max_time: float
    seeds: int
    best: float | None

    def hopeless(self, rows: list[dict]) -> bool:
        if not self.space.prune or self.best is None:
            return False
        bound = Score(tuple(rows)).best_possible(self.space.objective, self.max_time, self.seeds)
        return bound is not None and bound < self.best - 1e-12


def _run_seeds(
    trials: list[B.Trial],
    rows: list[dict],
    results: B.ResultsFile,
    runner: Runner,
    events: Events,
    limit: _Limit,
) -> bool | None:
    """Run the seeds of ``trials`` not in ``rows`` (rows of an earlier attempt), appending
    theirs; stop once the trial is hopeless. Returns whether it was pruned; None when
    interrupted."""
    for r in rows:
        events.row(r)
    if limit.hopeless(rows):
        return True
    seen = {int(r["seed"]) for r in rows}
    todo = [t for t in trials if t.seed not in seen]
    if not todo:
        return False

    def on_row(row: dict) -> None:
        rows.append(row)
        events.row(row)
        if limit.hopeless(rows):
            raise _Hopeless

    try:
        return False if runner(todo, results, on_row) else None
    except _Hopeless:
        return True


def run_study(
    target: Target,
    space: Space,
    opts: TuneOptions,
    runner: Runner,
    events: Events | None = None,
):
    """Run study trials until ``opts.trials`` have finished; returns the study, or None when
    interrupted (the trial then running is marked failed; a rerun resumes)."""
    import optuna
    from optuna.trial import TrialState

    events = events or Events()
    storage = open_storage(opts.out)
    study = open_study(target, space, opts, storage)
    results = B.ResultsFile(opts.out / "results.csv")
    first = baseline(target, space)
    max_time = target.scenario.episode.max_time
    while (done := len(_finished(study))) < opts.trials:
        study = optuna.load_study(
            study_name=STUDY,
            storage=storage,
            sampler=_sampler(opts.sampler_seed, done, space.startup(opts.trials)),
        )
        waiting = study.get_trials(deepcopy=False, states=(TrialState.WAITING,))
        if done == 0 and first is not None and not waiting:
            study.enqueue_trial(first, user_attrs={"original": True})
        trial = study.ask(space.distributions())
        values = {p.key: p.value(trial.params[p.key]) for p in space.params}
        scenario = write_variant(target, space, values, opts.out / "scenarios")
        trial.set_user_attr("values", values)
        trial.set_user_attr("scenario", str(Path(scenario.source).relative_to(opts.out)))
        case = dataclasses.replace(target.case, case=f"{target.case.case}@{values_id(values)}")
        evaluator = MetricsEvaluator(scenario)
        trials = [B.Trial(case, scenario, evaluator, s) for s in opts.seeds]
        keys = {B.trial_key(case.case, s, scenario.hash) for s in opts.seeds}
        rows = B.latest_rows(results.rows(), keys)
        best = (
            study.best_value
            if any(t.state == TrialState.COMPLETE for t in _finished(study))
            else None
        )
        limit = _Limit(space, max_time, len(opts.seeds), best)
        try:
            pruned = _run_seeds(trials, rows, results, runner, events, limit)
        except BaseException:
            study.tell(trial, state=TrialState.FAIL)
            raise
        if pruned is None:
            study.tell(trial, state=TrialState.FAIL)
            return None
        score = Score(tuple(sorted(rows, key=lambda r: int(r["seed"]))))
        objective = score.value(space.objective, max_time)
        trial.set_user_attr("successes", score.successes)
        trial.set_user_attr("seeds_run", score.trials)
        if pruned:
            events.skipped(len(opts.seeds) - score.trials)
            trial.report(objective, step=score.trials)
            study.tell(trial, state=TrialState.PRUNED)
        else:
            study.tell(trial, objective)
        events.trial(
            TrialOutcome(trial.number, values, score, "pruned" if pruned else "complete", objective)
        )
    return study


def best_values(study) -> tuple[Any, dict[str, Any]]:
    """The best complete trial and its scenario values."""
    best = study.best_trial
    return best, best.user_attrs["values"]


def write_overlay(target: Target, space: Space, values: dict[str, Any], out: Path) -> Path:
    path = out / "overlay.yaml"
    header = (
        f"# Written by m3p2i tune: {target.label}; space {space.source}.\n"
        f"# Run it: m3p2i run {path}{_run_options(target.case)}\n"
    )
    path.write_text(header + yaml.safe_dump(overlay(target, space, values), sort_keys=False))
    load_scenario(path)  # what the user runs must load
    return path


@dataclass(frozen=True)
class Held:
    """The held-out comparison: the original's and the tuned overlay's scores on the same
    seeds; ``complete``: every held-out seed ran for both (False: interrupted, a rerun
    finishes it)."""

    original: Score
    tuned: Score
    complete: bool


def holdout(
    target: Target, overlay_path: Path, opts: TuneOptions, runner: Runner, events: Events
) -> Held:
    """The original and the tuned overlay on the held-out seeds, both on a seed (``workers``
    seeds at once) before the next, so that an interrupted comparison is still one on the same
    seeds."""
    tuned = load_scenario(overlay_path)
    sides = [
        (target.case, target.scenario),
        (dataclasses.replace(target.case, case=f"{target.case.case}_tuned"), tuned),
    ]
    results = B.ResultsFile(opts.out / "results.csv")
    keys = [{B.trial_key(c.case, s, sc.hash) for s in opts.holdout} for c, sc in sides]
    have = [{int(r["seed"]) for r in B.latest_rows(results.rows(), k)} for k in keys]
    for k in keys:
        for r in B.latest_rows(results.rows(), k):
            events.row(r)
    evaluators = [MetricsEvaluator(sc) for _, sc in sides]
    todo = [
        [
            B.Trial(c, sc, ev, s)
            for (c, sc), ev, done in zip(sides, evaluators, have)
            if s not in done
        ]
        for s in opts.holdout
    ]
    todo = [t for t in todo if t]
    complete = True
    for i in range(0, len(todo), max(1, opts.workers)):
        chunk = [t for seed in todo[i : i + max(1, opts.workers)] for t in seed]
        if not runner(chunk, results, events.row):
            complete = False
            break
    rows = results.rows()
    scores = [
        Score(tuple(sorted(B.latest_rows(rows, k), key=lambda r: int(r["seed"])))) for k in keys
    ]
    common = {int(r["seed"]) for r in scores[0].rows} & {int(r["seed"]) for r in scores[1].rows}
    original, tuned_score = (
        Score(tuple(r for r in sc.rows if int(r["seed"]) in common)) for sc in scores
    )
    return Held(original, tuned_score, complete and len(common) == len(opts.holdout))


def write_holdout(held: Held, path: Path) -> None:
    """``holdout.csv``: the held-out rows alone, the original's then the tuned overlay's, in
    the bench's format, so that ``m3p2i report`` tabulates the comparison (docs/tune.md's
    table is such a block). Written whole and then moved into place: never half a file."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    rows = B.ResultsFile(tmp)
    for r in (*held.original.rows, *held.tuned.rows):
        rows.append(r)
    tmp.replace(path)


# -------------------------------------------------------------------------------------- seeds


def parse_seeds(text: str, option: str) -> tuple[int, ...]:
    """``0-9``, ``3``, ``0-4,10,12-13`` -> the seeds in order, each once."""
    seeds: list[int] = []
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if not m or (m.group(2) and int(m.group(2)) < int(m.group(1))):
            raise ConfigError(
                option,
                "",
                "not a seed range",
                text,
                "A-B (A <= B), a seed, or a comma list, e.g. 0-9",
            )
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) else lo
        seeds += [s for s in range(lo, hi + 1) if s not in seeds]
    return tuple(seeds)


# ------------------------------------------------------------------------------------- report


def _cell(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def importances(study) -> dict[str, float] | str:
    """Optuna's parameter importances over the complete trials (pruned ones are not used), or
    why there are none."""
    import optuna
    from optuna.trial import TrialState

    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len({json.dumps(t.params, sort_keys=True) for t in complete}) < 2:
        # the evaluator would share the importance out evenly: a number that says nothing
        return f"{len(complete)} complete trial(s) of distinct values; it needs 2 or more"
    try:
        return optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError, ImportError) as exc:
        return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def report(
    target: Target,
    space: Space,
    opts: TuneOptions,
    study,
    overlay_path: Path,
    held: Held | None,
) -> str:
    """``report.md``: the study's history, importances, best trial per seed, held-out
    comparison."""
    from optuna.trial import TrialState

    keys = [p.key for p in space.params]
    finished = [t for t in study.get_trials(deepcopy=False) if t.state != TrialState.WAITING]
    best, _ = best_values(study)
    rows = B.ResultsFile(opts.out / "results.csv").rows()
    wall = sum(_num(r.get("trial_wall")) or 0.0 for r in rows)
    max_time = target.scenario.episode.max_time
    lines = [
        f"# m3p2i tune: {target.scenario.name}",
        "",
        f"- target: {target.label}",
        f"- space: `{space.source}`: "
        + "; ".join(f"`{p.key}` {p.describe()}" for p in space.params),
        f"- objective (maximised): {space.objective.formula()}",
        f"- training seeds {seed_ranges(opts.seeds)}, held-out seeds "
        f"{seed_ranges(opts.holdout) if opts.holdout else 'none'}; TPE seed {opts.sampler_seed}, "
        f"{space.startup(opts.trials)} random proposals first; pruning "
        f"{'on' if space.prune else 'off'}",
        f"- {len(_finished(study))} trials finished; episodes' wall time {wall:.0f} s "
        f"(sum over {len(rows)} episodes in `results.csv`, on {machine()}, {versions()})",
        f"- best: trial {best.number}; overlay `{overlay_path}` "
        f"(`m3p2i run {overlay_path}{_run_options(target.case)}`)",
        "",
        "## Trials",
        "",
        "| trial | state | " + " | ".join(f"`{k}`" for k in keys) + " | success | time [s] | "
        "objective |",
        "|---:|---|" + "---:|" * len(keys) + "---:|---:|---:|",
    ]
    for t in finished:
        vals = t.user_attrs.get("values", {})
        state = t.state.name.lower() + (" (original)" if t.user_attrs.get("original") else "")
        ran = t.user_attrs.get("seeds_run")
        succ = f"{t.user_attrs['successes']}/{ran}" if ran else "—"
        objective = (
            t.value
            if t.value is not None
            else (
                t.intermediate_values[max(t.intermediate_values)] if t.intermediate_values else None
            )
        )
        tstats = _trial_score(t, target, rows, opts.seeds).time_stats() if ran else None
        lines.append(
            f"| {t.number}{' **best**' if t.number == best.number else ''} | {state} | "
            + " | ".join(_cell(vals.get(k, "—")) for k in keys)
            + f" | {succ} | {f'{tstats[0]:.2f}' if tstats else '—'} | "
            + (f"{objective:.4f}" if objective is not None else "—")
            + " |"
        )
    lines += [
        "",
        "A pruned trial stopped once it could no longer beat the best complete one, even with "
        "every seed left succeeding; its objective is over the seeds it ran. Failed: "
        "interrupted, proposed again.",
        "",
        "## Parameter importances",
        "",
    ]
    imp = importances(study)
    if isinstance(imp, str):
        lines.append(f"Not computable: {imp}")
    else:
        lines += ["| key | importance |", "|---|---:|"]
        lines += [f"| `{k}` | {v:.3f} |" for k, v in imp.items()]
        lines += ["", "Optuna's default evaluator over the complete trials; few trials, rough."]
    score = _trial_score(best, target, rows, opts.seeds)
    lines += [
        "",
        f"## Best trial ({best.number}) per seed",
        "",
        "| seed | status | reason | time [s] | position error [m] | collisions | log |",
        "|---:|---|---|---:|---:|---:|---|",
    ]
    for r in score.rows:
        lines.append(
            f"| {r['seed']} | {r['status']} | {r.get('reason') or ''} | {_fmt(r.get('time'))} | "
            f"{_fmt(r.get('position_error'), 3)} | {r.get('collisions') or '—'} | "
            f"`{r.get('log', '')}` |"
        )
    lines += ["", "## Held-out evaluation", ""]
    if held is None:
        lines.append(
            "No held-out seeds (--holdout): the tuned set is judged on its own seeds only."
        )
    else:
        ran = sorted(int(r["seed"]) for r in held.original.rows)
        left = seed_ranges(sorted(set(opts.holdout) - set(ran)))
        lines += [
            f"Seeds {seed_ranges(ran) if ran else 'none yet'}, none tuned on; "
            f"{target.case.mode_label}."
            + (
                ""
                if held.complete
                else f" Interrupted before seeds {left}: rerun the same command to finish."
            ),
            "",
            "| scenario | success (95 % Wilson interval) | time [s] | position error [m] | "
            "failed seeds | objective |",
            "|---|---:|---:|---:|---|---:|",
        ]
        for name, s in zip(
            (f"original ({target.base})", f"tuned (`{overlay_path}`)"), (held.original, held.tuned)
        ):
            if not s.trials:
                continue
            lo, hi = wilson(s.successes, s.trials)
            ts = s.time_stats()
            lines.append(
                f"| {name} | {s.successes}/{s.trials} ({100 * lo:.0f}-{100 * hi:.0f} %) | "
                f"{f'{ts[0]:.2f} ({ts[1]:.2f})' if ts else '—'} | "
                f"{s.mean('position_error', max_time):.3f} | "
                f"{', '.join(map(str, s.failed_seeds())) or 'none'} | "
                f"{s.value(space.objective, max_time):.4f} |"
            )
        lines += [
            "",
            "time: mean (std) simulated seconds to success over the successful trials.",
        ]
    return "\n".join(lines) + "\n"


def _run_options(case: B.BenchCase) -> str:
    """The ``m3p2i run`` options that reproduce the case's conditions."""
    opts = [f"--mode {case.mode}"] if case.mode != "lockstep" else []
    if case.plan_every > 1:
        opts.append(f"--plan-every {case.plan_every}")
    if case.max_rate:
        opts.append(f"--planner-max-rate {case.max_rate:g}")
    if case.realtime_factor != 1.0:
        opts.append(f"--realtime-factor {case.realtime_factor:g}")
    if case.faults:
        opts.append(f"--faults {case.faults}")
    if case.estimate_delays:
        opts.append("--estimate-delays")
    elif case.delays is not None:
        opts.append("--compensate")
    return (" " + " ".join(opts)) if opts else ""


def _trial_score(trial, target: Target, rows: list[dict], seeds: Sequence[int]) -> Score:
    values = trial.user_attrs.get("values", {})
    case = f"{target.case.case}@{values_id(values)}"
    mine = [r for r in rows if r["case"] == case and int(r["seed"]) in seeds]
    latest = {int(r["seed"]): r for r in mine}
    return Score(tuple(latest[s] for s in sorted(latest)))


def _fmt(cell: Any, digits: int = 2) -> str:
    v = _num(cell)
    return f"{v:.{digits}f}" if v is not None else "—"


# ---------------------------------------------------------------------------------------- CLI


def run_tune(
    target_spec: str,
    space_path: Path,
    trials: int,
    seeds: str,
    holdout_seeds: str | None,
    out: Path,
    workers: int,
    sampler_seed: int,
    timeout: float | None,
    ray: bool,
    ray_address: str | None,
    cpus_per_trial: int,
) -> None:
    """``m3p2i tune``: every input checked before any trial; the study with a progress bar;
    the overlay, the held-out comparison and the report. Exits 2 on bad input, 130 when
    interrupted (rerun to resume)."""
    import os
    import sys

    import typer
    from rich.console import Console

    from m3p2i.process_checks import scenario_errors

    console = Console(width=None if sys.stdout.isatty() else 200)

    def fail(message: str) -> None:
        typer.echo(f"error: {message}", err=True)
        raise typer.Exit(2)

    try:
        import optuna  # noqa: F401
    except ImportError:
        fail("m3p2i tune needs Optuna: pip install 'm3p2i[tune]'")
    try:
        space = load_space(space_path)
        target = resolve_target(target_spec, timeout)
        train = parse_seeds(seeds, "--seeds")
        held = parse_seeds(holdout_seeds, "--holdout") if holdout_seeds else ()
        if set(train) & set(held):
            raise ConfigError(
                "--holdout",
                "",
                "held-out seeds must not be tuned on",
                sorted(set(train) & set(held)),
                f"seeds outside --seeds {seeds}",
            )
        opts = TuneOptions(
            out=out,
            trials=trials,
            seeds=train,
            holdout=held,
            sampler_seed=sampler_seed,
            workers=workers or os.cpu_count() or 1,
        )
        console.print(f"checking the space {space.source} against {target.scenario.source}")
        problems = check_space(target, space, out / "scenarios", scenario_errors)
    except ConfigError as exc:
        fail(str(exc))
    if problems:
        for message in problems:
            typer.echo(f"error: {message}", err=True)
        raise typer.Exit(2)
    cluster = None
    if ray or ray_address:
        from m3p2i import bench_ray

        try:
            cluster = bench_ray.connect(ray_address, opts.workers)
        except bench_ray.RayUnavailable as exc:
            fail(str(exc))
        console.print(f"Ray: {cluster.describe()}, {cpus_per_trial} CPU(s) per episode")
    runner = make_runner(opts, target.timeout, cluster, cpus_per_trial)
    try:
        study = open_study(target, space, opts)
    except ConfigError as exc:
        fail(str(exc))
    left = max(0, trials - len(_finished(study)))
    console.print(
        f"{target.label}: {left} of {trials} trials to run on seeds {seed_ranges(train)} "
        f"({len(train)} episodes each, {opts.workers} at once), then "
        f"{2 * len(held)} held-out episodes; results in {out}"
    )
    with B.progress(console) as bar:
        task = bar.add_task("tune", total=left * len(train) + 2 * len(held))

        def row(r: dict) -> None:
            bar.update(
                task,
                advance=1,
                description=f"{r['case']} seed {r['seed']}: {r['reason'] or r['status']}",
            )

        def trial(t: TrialOutcome) -> None:
            shown = ", ".join(f"{k.rsplit('.', 1)[-1]}={_cell(v)}" for k, v in t.values.items())
            bar.console.print(
                f"trial {t.number} ({shown}): {t.score.successes}/{t.score.trials}, "
                f"objective {t.objective:.4f}{' (pruned)' if t.state == 'pruned' else ''}"
            )

        events = Events(row=row, skipped=lambda n: bar.update(task, advance=n), trial=trial)
        study = run_study(target, space, opts, runner, events)
        if study is None:
            console.print("interrupted: finished episodes are kept; run the same command to resume")
            raise typer.Exit(130)
        best, values = best_values(study)
        path = write_overlay(target, space, values, out)
        compared = holdout(target, path, opts, runner, events) if held else None
    text = report(target, space, opts, study, path, compared)
    (out / "report.md").write_text(text)
    if compared is not None and compared.original.trials:
        write_holdout(compared, out / "holdout.csv")
    console.print(f"best: trial {best.number}: {values}")
    if compared is not None:
        for name, s in (("original", compared.original), ("tuned", compared.tuned)):
            if not s.trials:
                continue
            lo, hi = wilson(s.successes, s.trials)
            console.print(
                f"held-out {name}: {s.successes}/{s.trials} ({100 * lo:.0f}-{100 * hi:.0f} %)"
            )
    console.print(f"overlay: {path} (m3p2i run {path}{_run_options(target.case)})")
    console.print(f"report: {out / 'report.md'}")
    if compared is not None and not compared.complete:
        console.print("interrupted: run the same command to finish the held-out seeds")
        raise typer.Exit(130)
