"""The Optuna study: trials proposed by a seeded TPE, each run as bench trials on the training seeds
and scored; hopeless trials pruned; the study resumable from OUT/study.db."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from m3p2i import bench as B
from m3p2i.tune.space import METRICS, Objective, Space
from m3p2i.tune.target import Target, baseline, values_id, write_variant
from server.evaluation.metrics import MetricsEvaluator
from shared.config import ConfigError

STUDY = "tune"  # the study's name in OUT/study.db


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

    @property
    def ended(self) -> int:
        """Episodes that reached their outcome, a success or a failure: not those the bench
        stopped with a reason (its wall-clock time-out, a process that died)."""
        return sum(not r.get("reason") for r in self.rows)

    def failed_seeds(self) -> list[int]:
        return sorted(int(r["seed"]) for r in self.rows if not _won(r))

    def mean(self, metric: str, max_time: float) -> float:
        """:data:`METRICS`' value of ``metric`` over the rows."""
        if metric == "success":
            return self.successes / self.trials
        if metric == "time":
            times = [cell_number(r.get("time")) for r in self.rows if _won(r)]
            times = [t for t in times if t is not None]
            return sum(times) / len(times) / max_time if times else 1.0
        values = [v for r in self.rows if (v := cell_number(r.get(metric))) is not None]
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
        times = [t for r in self.rows if _won(r) and (t := cell_number(r.get("time"))) is not None]
        if not times:
            return None
        mean = sum(times) / len(times)
        return mean, math.sqrt(sum((t - mean) ** 2 for t in times) / len(times))


def _won(row: dict) -> bool:
    return str(row.get("success")) in ("1", "True") and not row.get("reason")


def cell_number(cell: Any) -> float | None:
    """A results cell as a finite number, None when empty or not a number."""
    try:
        v = float(cell)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


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


def finished_trials(study) -> list:
    """The study's trials that ended: completed or pruned."""
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
    while (done := len(finished_trials(study))) < opts.trials:
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
            if any(t.state == TrialState.COMPLETE for t in finished_trials(study))
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


def trial_score(trial, target: Target, rows: list[dict], seeds: Sequence[int]) -> Score:
    """A study trial's score from ``rows`` (``results.csv``): the latest row of each of
    ``seeds`` for its values, in seed order."""
    values = trial.user_attrs.get("values", {})
    case = f"{target.case.case}@{values_id(values)}"
    mine = [r for r in rows if r["case"] == case and int(r["seed"]) in seeds]
    latest = {int(r["seed"]): r for r in mine}
    return Score(tuple(latest[s] for s in sorted(latest)))


def best_values(study) -> tuple[Any, dict[str, Any]]:
    """The best complete trial and its scenario values."""
    best = study.best_trial
    return best, best.user_attrs["values"]
