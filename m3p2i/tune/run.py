"""``m3p2i tune`` end to end: the study, the overlay, the held-out evaluation and the report."""

from __future__ import annotations

from pathlib import Path

from m3p2i import bench as B
from m3p2i.bench_report import seed_ranges, wilson
from m3p2i.tune.holdout import holdout, parse_seeds, write_holdout
from m3p2i.tune.report import cell_text, report
from m3p2i.tune.space import load_space
from m3p2i.tune.study import (
    Events,
    TrialOutcome,
    TuneOptions,
    best_values,
    finished_trials,
    make_runner,
    open_study,
    run_study,
)
from m3p2i.tune.target import check_space, resolve_target, run_options, write_overlay
from shared.config import ConfigError


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
    left = max(0, trials - len(finished_trials(study)))
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
            shown = ", ".join(f"{k.rsplit('.', 1)[-1]}={cell_text(v)}" for k, v in t.values.items())
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
    console.print(f"overlay: {path} (m3p2i run {path}{run_options(target.case)})")
    console.print(f"report: {out / 'report.md'}")
    if compared is not None and not compared.complete:
        console.print("interrupted: run the same command to finish the held-out seeds")
        raise typer.Exit(130)
