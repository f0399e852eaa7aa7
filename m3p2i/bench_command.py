"""``m3p2i bench``: its options, declared once, and the command in its steps: read the bench file
and the cases to run, check a sweep's variants, plan the trials not yet in ``results.csv``, run
them (a local pool of warm pairs, or Ray tasks), then print and write the summary."""

from __future__ import annotations

import functools
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from m3p2i.cli_support import plugin_args, terminate_as_interrupt, usage_error
from m3p2i.process_checks import scenario_errors
from planner_client.options import Plugins
from shared.config import ConfigError
from shared.protocol import MAX_SEED

if TYPE_CHECKING:  # the bench's modules load only when it runs: --help stays quick
    from m3p2i.bench import BenchConfig
    from m3p2i.sweep import Sweep

Config = Annotated[
    str, typer.Argument(help="Bench file: a name (m3p2i list bench) or a YAML path.")
]
Quick = Annotated[
    bool, typer.Option("--quick", help="A few trials per case (the file's quick_trials).")
]
Cases = Annotated[
    str | None,
    typer.Option(help="Comma-separated case names or patterns, e.g. 'navigation,corner*'."),
]
Out = Annotated[
    Path | None,
    typer.Option(
        help="Output folder (default runs/bench/CONFIG, with --quick runs/bench/CONFIG-quick); "
        "rerun with the same folder to resume."
    ),
]
Workers = Annotated[
    int,
    typer.Option(min=0, help="Trials at once, each a server + planner pair (0: one per core)."),
]
Trials = Annotated[
    int | None, typer.Option(min=1, help="Trials per case (overrides the file and --quick).")
]
TrialTimeout = Annotated[
    float | None,
    typer.Option(
        min=0.001,
        help="Wall-clock seconds per trial before both processes are killed (default: the file's).",
    ),
]
FirstSeed = Annotated[
    int, typer.Option(min=0, max=MAX_SEED, help="Seed of trial 0; trial i uses seed + i.")
]
Fresh = Annotated[
    bool,
    typer.Option(
        "--fresh",
        help="Start a new server + planner pair for every trial. By default each worker keeps "
        "its pair across a case's trials and begins each with a seeded reset: the same "
        "results, without ~2.5-5 s of start-up per trial.",
    ),
]
Sets = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Sweep a scenario key over values: KEY=V1,V2,... (repeatable; the product runs), "
        "e.g. --set planner.samples=50,100,200. Adds to or replaces the file's sweep: section.",
    ),
]
Ray = Annotated[
    bool,
    typer.Option(
        "--ray",
        help="Run the trials as Ray tasks on a local Ray instance of --workers CPUs (needs "
        "Ray: the 'cluster' extra of m3p2i).",
    ),
]
RayAddress = Annotated[
    str | None,
    typer.Option(
        help="Run the trials on the Ray cluster at this address (e.g. ray://head:10001 or "
        "auto); every node needs m3p2i installed."
    ),
]
CpusPerTrial = Annotated[
    int,
    typer.Option(
        min=1, help="With Ray: CPUs each trial declares, and the planner's rollout threads."
    ),
]


@dataclass(frozen=True)
class BenchRequest:
    """What ``m3p2i bench`` was asked (its options, as typed)."""

    config: str = "paper"
    quick: bool = False
    cases: str | None = None
    out: Path | None = None
    workers: int = 0
    trials: int | None = None
    timeout: float | None = None
    seed: int = 0
    fresh: bool = False
    sets: tuple[str, ...] = ()
    ray: bool = False
    ray_address: str | None = None
    cpus_per_trial: int = 1
    plugins: tuple[str, ...] = ()

    @property
    def workers_or_cores(self) -> int:
        return self.workers or os.cpu_count() or 1


def bench(
    config: Config = "paper",
    quick: Quick = False,
    cases: Cases = None,
    out: Out = None,
    workers: Workers = 0,
    trials: Trials = None,
    timeout: TrialTimeout = None,
    seed: FirstSeed = 0,
    fresh: Fresh = False,
    set_: Sets = None,
    ray: Ray = False,
    ray_address: RayAddress = None,
    cpus_per_trial: CpusPerTrial = 1,
    plugins: Plugins = None,
) -> None:
    """Run seeded trials of every case (Tables I-III), resumable; print and write the summary.

    With --set or a sweep: section, every case runs once per combination of the values; the
    summary adds one table and one plot (sweep-KEY.png) per swept key. With --ray or
    --ray-address the same trials run as Ray tasks; results and logs come back to OUT."""
    run_bench(
        BenchRequest(
            config=config,
            quick=quick,
            cases=cases,
            out=out,
            workers=workers,
            trials=trials,
            timeout=timeout,
            seed=seed,
            fresh=fresh,
            sets=tuple(set_ or ()),
            ray=ray,
            ray_address=ray_address,
            cpus_per_trial=cpus_per_trial,
            plugins=plugin_args(plugins),
        )
    )


@dataclass
class _Plan:
    """The bench file read for a request: its cases ready to run and those skipped (with the
    reason), the sweep, the output folder and the paper's figures."""

    cfg: BenchConfig
    out_dir: Path
    swept: Sweep
    ready: list
    skipped: list
    paper: dict  # case -> the published row (bench_report.load_paper)


def run_bench(req: BenchRequest) -> None:
    """``m3p2i bench`` for ``req``; exits 2 on a bad file or option, 130 when interrupted."""
    terminate_as_interrupt()
    from rich.console import Console

    from m3p2i import bench as B
    from m3p2i import bench_report as R

    # piped or logged output gets the whole table instead of 80 columns of wrapped cells
    console = Console(width=None if sys.stdout.isatty() else 200)
    plan = _read(req)
    if plan.swept.keys:
        _check_variants(req, plan, console)
    opts = B.BenchOptions(
        out_dir=plan.out_dir,
        workers=req.workers_or_cores,
        timeout=req.timeout or plan.cfg.timeout,
        trials=req.trials,
        quick=req.quick,
        seed=req.seed,
        fresh=req.fresh,
        plugins=req.plugins,
    )
    if (req.ray or req.ray_address) and opts.plugins:
        usage_error(
            "--plugins: a Ray node imports no module the driver names (the planner's plugins "
            "are the node operator's choice); run the bench on this machine's pool"
        )
    results = B.ResultsFile(plan.out_dir / "results.csv")
    done = {B.trial_key(r["case"], r["seed"], r["scenario_hash"]) for r in results.rows()}
    planned, todo = B.plan_trials(plan.ready, plan.cfg, opts, done)
    if planned and (last := max(t.seed for t in planned)) > MAX_SEED:
        usage_error(
            f"--seed {req.seed}: its trials' seeds reach {last} (expected at most {MAX_SEED})"
        )
    for s in plan.skipped:
        console.print(f"[yellow]skipped[/] {s.case.case}: {s.reason}")
    variants = len(plan.swept.variants())
    shape = (
        f"{len(plan.ready) // variants} cases × {variants} variants"
        if plan.swept.keys
        else f"{len(plan.ready)} cases"
    )
    console.print(
        f"{len(planned)} trials in {shape}, {len(planned) - len(todo)} already "
        f"in {results.path}, {len(todo)} to run on {opts.workers} workers "
        f"(time-out {opts.timeout:.0f} s each)"
    )
    finished = _run(req, todo, opts, results, console)
    rows, table = _table(plan, planned, results)
    title = f"m3p2i bench {Path(plan.cfg.source).stem}{' --quick' if req.quick else ''}"
    console.print(R.rich_table(table, title))
    if req.cases:
        # the folder's summary.md covers every case of the bench file, not only those just run
        plan = _read(replace(req, cases=None))
        rows, table = _table(plan, B.plan_trials(plan.ready, plan.cfg, opts, done)[0], results)
    _write_summary(plan, rows, table, title, results, console)
    if not finished:
        console.print("interrupted: finished trials are kept; run the same command to resume")
        raise typer.Exit(130)


def _read(req: BenchRequest) -> _Plan:
    """The bench file, the cases asked for and the sweep (exit 2 on any error of them)."""
    from m3p2i import bench as B
    from m3p2i import bench_report as R
    from m3p2i import sweep as S

    try:
        cfg = B.load_bench(req.config)
        # --quick has its own folder: its trials are seeds 0-1 of the full run's, but its
        # summary must not replace the full run's summary.md
        out_dir = req.out or Path("runs") / "bench" / (
            Path(cfg.source).stem + ("-quick" if req.quick else "")
        )
        swept = cfg.sweep.merged(S.parse_set(list(req.sets))) if req.sets else cfg.sweep
        ready, skipped = B.select_cases(
            cfg,
            [c.strip() for c in req.cases.split(",")] if req.cases else None,
            swept,
            out_dir / "scenarios",
        )
        return _Plan(cfg, out_dir, swept, ready, skipped, R.load_paper())
    except ConfigError as exc:
        usage_error(str(exc))


def _check_variants(req: BenchRequest, plan: _Plan, console) -> None:
    """The loader checked each variant's keys and values; what only the processes resolve
    (cost-term parameters, names in the model) is checked by them now, not trial by trial."""
    from m3p2i import bench as B

    console.print(f"checking {len(plan.ready)} scenario variants (both processes' --check)")
    problems = B.check_variants(
        plan.ready,
        req.workers_or_cores,
        functools.partial(scenario_errors, plugins=req.plugins),
    )
    if problems:
        for message in problems:
            typer.echo(f"error: {message}", err=True)
        raise typer.Exit(2)


def _run(req: BenchRequest, todo: list, opts, results, console) -> bool:
    """Run ``todo`` on the local pool or on Ray, a progress bar advancing per trial; False
    when interrupted."""
    from m3p2i import bench as B
    from m3p2i import sweep as S

    cluster = None
    if req.ray or req.ray_address:
        from m3p2i import bench_ray

        try:
            cluster = bench_ray.connect(req.ray_address, opts.workers)
        except bench_ray.RayUnavailable as exc:
            usage_error(str(exc))
        console.print(f"Ray: {cluster.describe()}, {req.cpus_per_trial} CPU(s) per trial")
    with B.progress(console) as bar:
        task = bar.add_task("bench", total=len(todo))

        def done(row: dict) -> None:
            label = f" ({S.label(S.from_cell(row['overrides']))})" if row.get("overrides") else ""
            bar.update(
                task,
                advance=1,
                description=f"{row['case']}{label} seed {row['seed']}: "
                f"{row['reason'] or row['status']}",
            )

        if cluster is not None:
            return bench_ray.run_trials(todo, opts, results, cluster, req.cpus_per_trial, done)
        return B.run_trials(todo, opts, results, on_done=done)


def _table(plan: _Plan, planned: list, results) -> tuple[list[dict], list]:
    """The planned trials' newest rows and their summary table (a sweep's variants are rows
    of their own: "push (samples=50)")."""
    from m3p2i import bench as B
    from m3p2i import bench_report as R
    from m3p2i import sweep as S

    keys = {B.trial_key(t.case.case, t.seed, t.scenario.hash) for t in planned}
    rows = B.latest_rows(results.rows(), keys)
    labelled = [{**r, "case": S.variant_case(r)} for r in rows]
    order = [
        S.variant_case({"case": rc.case.case, "overrides": S.to_cell(rc.overrides)})
        for rc in plan.ready
    ]
    return rows, R.table_rows(R.summarize(labelled, order), plan.paper)


def _write_summary(plan: _Plan, rows: list[dict], table: list, title: str, results, console):
    """OUT/summary.md: the table (with a sweep, one table and one plot per swept key)."""
    from m3p2i import bench_report as R
    from m3p2i import sweep as S

    header = (
        f"# {title}\n\n{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores; "
        f"results: `{results.path}`"
    )
    out_dir = plan.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    text = R.markdown_report(table, [(s.case.case, s.reason) for s in plan.skipped], header)
    if plan.swept.keys:
        text += "\n" + S.sweep_report(rows)
        console.print(S.sweep_report(rows), markup=False)
        try:
            for path in S.plot_sweep(rows, out_dir):
                console.print(f"plot: {path}")
        except ImportError:
            console.print(
                "[yellow]no sweep plot[/]: it needs matplotlib: pip install 'm3p2i[plots]'"
            )
    (out_dir / "summary.md").write_text(text)
    console.print(f"summary: {out_dir / 'summary.md'}")
