"""``m3p2i tune`` end to end: the study, the overlay, the held-out evaluation and the report."""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import typer

from m3p2i import bench as B
from m3p2i.bench_report import seed_ranges, wilson
from m3p2i.tune.holdout import Held, holdout, parse_seeds, write_holdout
from m3p2i.tune.report import cell_text, report
from m3p2i.tune.space import Space, load_space
from m3p2i.tune.study import (
    Events,
    Runner,
    TrialOutcome,
    TuneOptions,
    best_values,
    finished_trials,
    make_runner,
    open_study,
    run_study,
    trial_score,
)
from m3p2i.tune.target import Target, check_space, resolve_target, run_options, write_overlay
from shared.config import ConfigError


@dataclass(frozen=True)
class _Setup:
    """A study's inputs, each checked: what is tuned, over which space, with which options."""

    target: Target
    space: Space
    opts: TuneOptions


@dataclass(frozen=True)
class _Found:
    """What a study found: its best trial and values, the overlay of them and the held-out
    comparison (None without --holdout)."""

    study: Any  # optuna.Study
    best: Any  # optuna FrozenTrial
    values: dict[str, Any]
    overlay: Path
    compared: Held | None


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
    the overlay, the held-out comparison and the report. Exits 2 on bad input, 1 when no
    trial finished an episode (nothing to choose from), 130 when interrupted (rerun to
    resume)."""
    import sys

    from rich.console import Console

    console = Console(width=None if sys.stdout.isatty() else 200)
    _require_optuna()
    try:
        space = load_space(space_path)
        target = resolve_target(target_spec, timeout)
        train, held = _read_seeds(seeds, holdout_seeds)
        opts = TuneOptions(
            out=out,
            trials=trials,
            seeds=train,
            holdout=held,
            sampler_seed=sampler_seed,
            workers=workers or os.cpu_count() or 1,
        )
        setup = _Setup(target, space, opts)
        _check_space_or_exit(setup, console)
    except ConfigError as exc:
        _fail(str(exc))
    cluster = _connect_ray(ray, ray_address, setup.opts.workers, cpus_per_trial, console)
    runner = make_runner(setup.opts, setup.target.timeout, cluster, cpus_per_trial)
    found = _search(setup, runner, console)
    _write_report(setup, found)
    _print_outcome(setup, found, console)


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _require_optuna() -> None:
    try:
        import optuna  # noqa: F401
    except ImportError:
        _fail("m3p2i tune needs Optuna: pip install 'm3p2i[tune]'")


def _read_seeds(seeds: str, holdout_seeds: str | None) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The training and held-out seeds; ConfigError when they overlap (a held-out seed must
    judge the tuned set on an episode it was not chosen on)."""
    train = parse_seeds(seeds, "--seeds")
    held = parse_seeds(holdout_seeds, "--holdout") if holdout_seeds is not None else ()
    if set(train) & set(held):
        raise ConfigError(
            "--holdout",
            "",
            "held-out seeds must not be tuned on",
            sorted(set(train) & set(held)),
            f"seeds outside --seeds {seeds}",
        )
    return train, held


def _check_space_or_exit(setup: _Setup, console) -> None:
    """Every value of the space read by the scenario loader (ConfigError), and its corners
    by both processes' ``--check``, whose messages exit 2 together."""
    from m3p2i.process_checks import scenario_errors

    target, space = setup.target, setup.space
    console.print(f"checking the space {space.source} against {target.scenario.source}")
    problems = check_space(target, space, setup.opts.out / "scenarios", scenario_errors)
    if problems:
        for message in problems:
            typer.echo(f"error: {message}", err=True)
        raise typer.Exit(2)


def _connect_ray(ray: bool, address: str | None, workers: int, cpus_per_trial: int, console):
    """The Ray cluster the episodes run on, None for the local pool."""
    if not (ray or address):
        return None
    from m3p2i import bench_ray

    try:
        cluster = bench_ray.connect(address, workers)
    except bench_ray.RayUnavailable as exc:
        _fail(str(exc))
    console.print(f"Ray: {cluster.describe()}, {cpus_per_trial} CPU(s) per episode")
    return cluster


def _search(setup: _Setup, runner: Runner, console) -> _Found:
    """The study run to its trials with a progress bar, then the overlay of its best set and
    the held-out comparison. Exits 130 when interrupted, 1 when no trial finished."""
    target, space, opts = setup.target, setup.space, setup.opts
    try:
        study = open_study(target, space, opts)
    except ConfigError as exc:
        _fail(str(exc))
    left = max(0, opts.trials - len(finished_trials(study)))
    console.print(
        f"{target.label}: {left} of {opts.trials} trials to run on seeds "
        f"{seed_ranges(opts.seeds)} ({len(opts.seeds)} episodes each, {opts.workers} at once), "
        f"then {2 * len(opts.holdout)} held-out episodes; results in {opts.out}"
    )
    with B.progress(console) as bar:
        task = bar.add_task("tune", total=left * len(opts.seeds) + 2 * len(opts.holdout))
        events = _progress_events(bar, task)
        study = run_study(target, space, opts, runner, events)
        if study is None:
            console.print("interrupted: finished episodes are kept; run the same command to resume")
            raise typer.Exit(130)
        unfinished = _no_outcome(setup, study)
        if unfinished:
            typer.echo(f"error: {unfinished}", err=True)
            raise typer.Exit(1)
        best, values = best_values(study)
        path = write_overlay(target, space, values, opts.out)
        compared = holdout(target, path, opts, runner, events) if opts.holdout else None
    return _Found(study, best, values, path, compared)


def _progress_events(bar, task) -> Events:
    """The study's events shown on ``bar``: each episode advances it, each trial is a line."""

    def row(r: dict) -> None:
        bar.update(
            task,
            advance=1,
            description=f"{r['case']} seed {r['seed']}: {r['reason'] or r['status']}",
        )

    def trial(t: TrialOutcome) -> None:
        shown = ", ".join(f"{k.rsplit('.', 1)[-1]}={cell_text(v)}" for k, v in t.values.items())
        bar.console.print(
            f"trial {t.number} ({shown}): {t.score.successes}/{t.score.trials}, "
            f"objective {t.objective:.4f}{' (pruned)' if t.state == 'pruned' else ''}"
        )

    return Events(row=row, skipped=lambda n: bar.update(task, advance=n), trial=trial)


def _no_outcome(setup: _Setup, study) -> str | None:
    """Why the study has no best trial when none of its episodes reached an outcome (every one
    stopped by the wall-clock time-out or an error); None when one did. Its objective values
    are then those of no data: naming a best trial would pass a guess off as a result."""
    opts = setup.opts
    rows = B.ResultsFile(opts.out / "results.csv").rows()
    trials = finished_trials(study)
    scores = [trial_score(t, setup.target, rows, opts.seeds) for t in trials]
    if any(s.ended for s in scores):
        return None
    reasons = Counter(r.get("reason") for s in scores for r in s.rows)
    why = ", ".join(f"{reason}: {n}" for reason, n in reasons.most_common())
    # the study in OUT keeps these trials and rows: a rerun there would find the same
    hint = (
        f" (is the time-out, {setup.target.timeout:g} s, shorter than an episode takes? a "
        "longer --timeout and another --out start afresh)"
        if "timeout" in reasons
        else ""
    )
    return (
        f"no trial finished: none of the {sum(reasons.values())} episodes of the "
        f"{len(trials)} trials reached an outcome ({why}), so there is no best set; no overlay "
        f"or report written. The episodes are in {opts.out / 'results.csv'} and "
        f"{opts.out / 'logs'}{hint}"
    )


def _write_report(setup: _Setup, found: _Found) -> None:
    """``OUT/report.md``, and ``OUT/holdout.csv`` once a held-out seed ran."""
    out = setup.opts.out
    text = report(setup.target, setup.space, setup.opts, found.study, found.overlay, found.compared)
    (out / "report.md").write_text(text)
    if found.compared is not None and found.compared.original.trials:
        write_holdout(found.compared, out / "holdout.csv")


def _print_outcome(setup: _Setup, found: _Found, console) -> None:
    """The best set, its held-out success beside the original's and where the files are;
    exits 130 when the held-out seeds were interrupted."""
    out, compared = setup.opts.out, found.compared
    console.print(f"best: trial {found.best.number}: {found.values}")
    if compared is not None:
        for name, s in (("original", compared.original), ("tuned", compared.tuned)):
            if not s.trials:
                continue
            lo, hi = wilson(s.successes, s.trials)
            console.print(
                f"held-out {name}: {s.successes}/{s.trials} ({100 * lo:.0f}-{100 * hi:.0f} %)"
            )
    console.print(
        f"overlay: {found.overlay} (m3p2i run {found.overlay}{run_options(setup.target.case)})"
    )
    console.print(f"report: {out / 'report.md'}")
    if compared is not None and not compared.complete:
        console.print("interrupted: run the same command to finish the held-out seeds")
        raise typer.Exit(130)
