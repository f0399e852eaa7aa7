"""``m3p2i``: the umbrella command. ``m3p2i run SCENARIO`` starts server and planner as two
processes (exactly what two terminals would run), waits for the episode and reports it.

It launches ``python -m server`` and ``python -m planner_client``: the two sides still meet only
over the wire.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from m3p2i.bench_command import bench
from m3p2i.cli_support import (
    VIDEO_FORMATS,
    Fps,
    Height,
    RunDir,
    ScenarioArgument,
    Seed,
    Speed,
    Timeout,
    Width,
    declared_delays_or_exit,
    faults_or_exit,
    flow_help,
    keys_or_exit,
    load_or_exit,
    plugin_args,
    terminate_as_interrupt,
    usage_error,
)
from m3p2i.launch import (
    EpisodeLaunch,
    died,
    free_port_block,
    log_tail,
    run_episode,
    taken_ports,
)
from m3p2i.new import new_scenario
from m3p2i.process_checks import error_blocks
from m3p2i.view_command import view
from planner_client.options import MeasureDelays, OldMeasureDelays, Plugins
from server.evaluation.plan_ages import describe_timing
from server.options import (
    Faults,
    Mode,
    OldFaults,
    OldWindow,
    PlanEvery,
    RealtimeFactor,
    Window,
    default_run_dir,
    mode_conflicts,
    summary_line,
)
from shared.cli_common import LAST_FIRST_PORT, Keys, Verbose, renamed
from shared.config import ConfigError, load_yaml
from shared.config_files import ENV_VAR, KINDS, Entry, entries, search_folders, shown
from shared.robots import load_robot, registered
from shared.scenario import load_scenario

__all__ = ["app", "free_port_block"]  # free_port_block: tests start processes with it

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help=(
        "m3p2i: reactive task and motion planning with active inference and multi-modal MPPI.\n\n"
        "`m3p2i run navigation` runs a scenario end to end; `m3p2i list` shows the scenarios and "
        "where each comes from, `m3p2i new NAME --from SCENARIO` starts your own; "
        "`m3p2i layout SCENARIO` prints what a hardware bridge must send and accept. "
        "For two terminals use `m3p2i-server` and `m3p2i-planner` directly."
    ),
)


@app.command("check")
def check(scenario: ScenarioArgument, plugins: Plugins = None) -> None:
    """Check SCENARIO as both processes would, without starting them: every error of the file
    at once (frames, actuators, cost terms, observers included); exit 0 when sound, 2 if not."""
    sc = load_or_exit(scenario, plugin_args(plugins))
    typer.echo(f"{sc.source}: ok")


@app.command("layout")
def layout(
    scenario: ScenarioArgument,
    as_json: bool = typer.Option(
        False,
        "--json",
        help="Print one JSON object instead of "
        "tables (keys: scenario, scenario_hash, robot, dt, sizes, nu, "
        "qpos, qvel, act, mocap, ctrl, extras, sensors, perceived, frames), for bridges "
        "and tools in other languages.",
    ),
) -> None:
    """Print what a world (a hardware bridge) must send and accept for SCENARIO, by name:
    each index of state.qpos and state.qvel with its joint, component, unit and frame; each
    row of mocap_pos/mocap_quat with its body; each index of command.ctrl with its actuator,
    unit, range and safe value; the state.extras the scenario needs; the sensors of state.scans
    (name, kind, rays or image size, rate, frame). Then the frames the
    scenario's YAML may name: the robot's bodies and sites (site:NAME), the objects, the walls.

    The planner stops (exit code 3) when a world's first state has other sizes than these."""
    import json
    from dataclasses import asdict

    from rich.console import Console

    from m3p2i.bridge_layout import bridge_layout, frame_names
    from m3p2i.layout_table import print_frames, print_layout
    from shared.scene import compile_model

    try:
        sc = load_scenario(scenario)
        model = compile_model(sc)
        # the state's layout is the planner's model (without perceived objects), the frames
        # the world's
        found, frames = bridge_layout(sc), frame_names(sc, model)
    except (ConfigError, ValueError) as exc:
        usage_error(str(exc))
    if as_json:
        typer.echo(json.dumps({**found.to_dict(), "frames": [asdict(f) for f in frames]}, indent=1))
        return
    console = Console(width=None if sys.stdout.isatty() else 200)
    print_layout(found, console)
    print_frames(frames, console)


Compensate = Annotated[
    bool,
    typer.Option(
        "--compensate",
        help="Declare the simulated faults' actuation and state delays to the planner (as a "
        "robot's owner who measured them would, in planner.delays): it plans from the state "
        "predicted for when its plan acts.",
    ),
]
PlannerMaxRate = Annotated[
    float,
    typer.Option(
        min=0.0,
        help="realtime: the planner makes at most this many plans per second (0: as fast as it "
        "can): a slower computer, rehearsed.",
    ),
]
FirstPort = Annotated[
    int,
    typer.Option(
        min=0,
        max=LAST_FIRST_PORT,
        help="The world's first port, as m3p2i-server --port (0: pick a free block of ports).",
    ),
]
View = Annotated[
    bool,
    typer.Option(
        "--view",
        help="Serve the browser view (m3p2i view) of the episode and print its URL; needs "
        "m3p2i\\[view].",
    ),
]
ViewPort = Annotated[
    int, typer.Option(min=0, max=65535, help="With --view: the page's port (0: a free one).")
]
ViewExit = Annotated[
    bool | None,
    typer.Option(
        "--view-exit/--view-keep",
        help="With --view, once the episode is over: exit, or keep the page up showing the "
        "episode's replay until Ctrl-C (then exit with the episode's code). Default: keep when "
        "stdin and stdout are a terminal, exit otherwise (scripts, tests).",
    ),
]


@app.command("run")
def run(
    scenario: ScenarioArgument,
    mode: Mode = "lockstep",
    plan_every: PlanEvery = 1,
    faults: Faults = None,
    compensate: Compensate = False,
    measure_delays: MeasureDelays = False,
    plugins: Plugins = None,
    planner_max_rate: PlannerMaxRate = 0.0,
    realtime_factor: RealtimeFactor = 1.0,
    port: FirstPort = 0,
    run_dir: RunDir = None,
    timeout: Timeout = 900.0,
    window: Window = False,
    view: View = False,
    view_port: ViewPort = 0,
    view_exit: ViewExit = None,
    seed: Seed = 0,
    verbose: Verbose = False,
    keys: Keys = None,
    hardware: OldFaults = None,
    viewer: OldWindow = False,
    estimate_delays: OldMeasureDelays = False,
) -> None:
    """Run one episode of SCENARIO with server and planner; exit 0 on success, 1 otherwise (a
    process that died is named, with the last lines of its log), 2 on a configuration error."""
    faults = renamed(faults, hardware, "--faults", "--hardware", None)
    window = renamed(window, viewer, "--window", "--viewer", False)
    measure_delays = renamed(
        measure_delays, estimate_delays, "--measure-delays", "--estimate-delays", False
    )
    _modes_or_exit(mode, plan_every, planner_max_rate, realtime_factor)
    if faults is not None:  # first: a mistyped profile is refused at once
        faults = faults_or_exit(faults)
    # the checks that need no scenario first: the processes' checks of it take seconds
    if view_port and not view:
        usage_error("--view-port serves the page of --view: give --view too, or leave it out")
    _ports_or_exit(port, view_port if view else 0)
    keys_or_exit(keys)
    sc = load_or_exit(scenario, plugin_args(plugins))
    delays = declared_delays_or_exit(sc, faults) if compensate else None
    run_dir = run_dir or default_run_dir(sc.name)
    typer.echo(
        f"running {sc.name} ({mode}{', faults ' + faults if faults else ''}"
        f"{', delays compensated' if delays else ''}"
        f"{', delays estimated' if measure_delays else ''}); logs in {run_dir}"
    )
    if view_exit is None:  # an interactive run keeps its page; a script must not block
        view_exit = not (sys.stdin.isatty() and sys.stdout.isatty())
    launch = EpisodeLaunch(
        scenario=sc.source,
        run_dir=run_dir,
        seed=seed,
        mode=mode,
        port=port,
        timeout=timeout,
        window=window,
        verbose=verbose,
        plan_every=plan_every,
        view=view,
        view_port=view_port,
        keys=keys,
        view_keep=view and not view_exit,
        faults=faults or "",
        delays=delays,
        measure_delays=measure_delays,
        max_rate=planner_max_rate,
        realtime_factor=realtime_factor,
        plugins=plugin_args(plugins),
    )
    raise typer.Exit(_launch(launch, sc.name))


def _ports_or_exit(port: int, view_port: int) -> None:
    """A port asked for that another process holds: exit 2 before anything starts (the world
    would fail to bind it, the view would move to another port than the one waited on)."""
    for flag, first, count in (("--port", port, 4), ("--view-port", view_port, 1)):
        if first and (busy := taken_ports(first, count)):
            usage_error(
                f"{flag} {first}: port {busy[0]} is taken (leave {flag} out to pick free ones)"
            )


def _modes_or_exit(mode: str, plan_every: int, max_rate: float, realtime_factor: float) -> None:
    """Options that belong to the other mode (``--plan-every`` in real time, ...): exit 2."""
    flags = {
        "mode": "--mode",
        "max_rate": "--planner-max-rate",
        "realtime_factor": "--realtime-factor",
        "plan_every": "--plan-every",
    }
    for key, why, value, expected in mode_conflicts(mode, plan_every, max_rate, realtime_factor):
        expected = expected.replace("mode: ", "--mode ").replace("plan_every", "--plan-every")
        usage_error(f"{flags[key]} {value}: {why} (expected {expected})")


def _launch(launch: EpisodeLaunch, name: str) -> int:
    """Run the episode of ``launch`` (printing the view's URL, and keeping the page when asked)
    and report it: the exit code."""
    codes = []

    def report(result) -> int:
        return _report_run(
            result, name, launch.run_dir, launch.timeout, launch.mode, launch.plan_every
        )

    def kept(result, url: str) -> None:
        codes.append(report(result))
        typer.echo(f"episode over; view still at {url}: Ctrl-C to quit")
        sys.stdout.flush()

    try:
        result = run_episode(launch, on_view=lambda url: typer.echo(f"view: {url}"), on_kept=kept)
    except RuntimeError as exc:  # the view could not serve its page
        usage_error(str(exc))
    return codes[0] if codes else report(result)


def _report_run(
    result, name: str, run_dir: Path, timeout: float, mode: str, plan_every: int
) -> int:
    """``m3p2i run``'s report of an episode (its outcome, or why it has none): the exit code."""
    if result.reason == "timeout":
        typer.echo(f"error: no outcome within {timeout:.0f} s; stopping", err=True)
    elif result.reason == "interrupted":
        typer.echo("interrupted")
    elif result.reason:
        log_file = run_dir / f"{died(result.reason) or 'planner'}.log"
        # the process's own messages first: the log file is the place to look only for more
        blocks = error_blocks(log_file.read_text()) if log_file.is_file() else []
        for message in blocks:
            typer.echo(f"error: {message}", err=True)
        said = {line for m in blocks for line in m.splitlines()}
        tail = [line for line in log_tail(log_file) if line.removeprefix("error: ") not in said]
        typer.echo(
            f"error: the {result.reason}; "
            + (f"the last lines of {log_file}:" if tail else f"see {log_file}"),
            err=True,
        )
        for line in tail:
            typer.echo(f"  {line}", err=True)
    summary = result.summary
    if summary is None:
        typer.echo(f"error: no episode summary in {result.log_path}", err=True)
        return 1
    measures = dict(summary.get("measures", {}), planner_hz=summary.get("planner_hz", 0.0))
    typer.echo(f"{name}: " + summary_line(summary["status"], summary["time"], measures))
    if summary.get("timing") and (mode == "realtime" or plan_every > 1):
        typer.echo(f"timing: {describe_timing(summary['timing'])}")
    return 0 if summary["status"] == "success" else 1


app.command("bench")(bench)


@app.command("report")
def report(
    results: list[Path] | None = typer.Argument(
        None, help="results.csv files or bench output folders to tabulate together."
    ),
    update: list[Path] | None = typer.Option(
        None,
        "--update",
        help="Markdown file whose "
        "`<!-- m3p2i report PATH... -->` blocks are "
        "regenerated in place (repeatable).",
    ),
    check: bool = typer.Option(
        False,
        "--check",
        help="With --update: change nothing; exit 1 "
        "when a block differs from what its results give.",
    ),
    plots: Path | None = typer.Option(
        None,
        "--plots",
        help="Folder for the sweep plots of "
        "RESULTS (sweep-KEY.png: success and time against "
        "each swept key's value, one line per case).",
    ),
) -> None:
    """Tables from bench results: success with its 95 % Wilson interval, the paper's metrics,
    the machine and date of the trials, every failure with its note (failures.yaml beside
    results.csv). README and docs tables are made this way, never by hand."""
    from m3p2i import bench_report as R

    if not results and not update:
        usage_error("give results files to tabulate, or --update FILE")
    if check and not update:  # it would have checked nothing and passed
        usage_error("--check checks the blocks of --update FILE: give --update")
    try:
        paper = R.load_paper()
        if results:
            read = [R.read_results(p) for p in results]
            typer.echo(R.results_report(read, paper), nl=False)
            if plots is not None:
                from m3p2i.sweep import plot_sweep

                for path in plot_sweep([r for res in read for r in res.rows], plots):
                    typer.echo(f"wrote {path}")
        stale = []
        for doc in update or []:
            text = doc.read_text()
            new = R.update_reports(text, doc.parent, paper)
            if new != text:
                stale.append(doc)
                if not check:
                    doc.write_text(new)
    except (ConfigError, OSError) as exc:
        usage_error(str(exc))
    for doc in stale:
        typer.echo(f"{doc}: {'out of date' if check else 'updated'}")
    if check and stale:
        raise typer.Exit(1)


@app.command("plot")
def plot(
    log: Path = typer.Argument(
        ..., help="Episode log (episode.jsonl) or the run folder holding it."
    ),
    out: Path = typer.Option(Path("."), help="Folder for episode.png."),
    scenario: str | None = typer.Option(
        None, help="Scenario to replay the log into (default: the file named in the log's header)."
    ),
) -> None:
    """Plot one episode like thesis Figs. A.3-A.5: trajectories, distances,
    robot-object-goal angle."""
    from m3p2i.plots import episode_series, plot_episode
    from server.evaluation import log_reader

    try:
        path = log_reader.find_log(log)
        records = log_reader.read_log(path)
        sc = log_reader.log_scenario(records, scenario)
        series = episode_series(sc, records)
    except (ConfigError, FileNotFoundError, ValueError) as exc:
        usage_error(str(exc))
    head = log_reader.header(records)
    title = f"{sc.name}, seed {head.get('seed', '?')}"
    try:
        typer.echo(f"wrote {plot_episode(series, out / 'episode.png', title)}")
    except ImportError:
        usage_error("m3p2i plot needs matplotlib: pip install -e '.[plots]'")


@app.command("record")
def record(
    scenario: str | None = typer.Argument(
        None, help="Scenario to run and record (name or path); leave out with --log."
    ),
    out: Path = typer.Option(..., help="Video file: .gif (Pillow) or .mp4 (needs ffmpeg)."),
    log: Path | None = typer.Option(
        None, help="Render this episode log (or run folder) instead of running an episode."
    ),
    seed: Seed = 0,
    run_dir: RunDir = None,
    timeout: Timeout = 900.0,
    width: Width = 480,
    height: Height = 360,
    fps: Fps = 20.0,
    speed: Speed = 1.0,
    keys: Keys = None,
) -> None:
    """Record an episode offscreen (EGL or OSMesa) to GIF/MP4, with the planner's best sampled
    trajectories drawn in green."""
    if (scenario is None) == (log is None):
        usage_error("give a SCENARIO to run, or --log to render an existing episode")
    if out.suffix.lower() not in VIDEO_FORMATS:  # before an episode that could not be written
        usage_error(f"--out {out}: expected a {' or '.join(VIDEO_FORMATS)} file")
    from m3p2i import video

    try:
        backend = video.gl_backend()  # before the episode: no point running one we cannot draw
    except video.NoGLError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(3) from None
    if log is None:
        planner_keys = keys_or_exit(keys)
        sc = load_or_exit(scenario)
        run_dir = run_dir or default_run_dir(sc.name)
        run_dir.mkdir(parents=True, exist_ok=True)
        port = free_port_block()
        recorder = video.DiagnosticsRecorder(
            port, run_dir / video.DIAGNOSTICS_FILE, keys=planner_keys
        )
        try:
            result = run_episode(
                EpisodeLaunch(
                    scenario=sc.source,
                    run_dir=run_dir,
                    seed=seed,
                    port=port,
                    timeout=timeout,
                    keys=keys,
                )
            )
        finally:
            recorder.close()
        status = result.summary["status"] if result.summary else result.reason or "no summary"
        typer.echo(f"{sc.name}: {status}; logs in {run_dir}")
        log = result.log_path
    try:
        video.render_in_child(backend, log, out, width - width % 2, height - height % 2, fps, speed)
    except RuntimeError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    typer.echo(f"wrote {out}")


app.command("view")(view)


@app.command("keys")
def keys_command(
    folder: Path = typer.Argument(
        ...,
        help="Folder to create the keys in (made if missing; existing keys are never replaced).",
    ),
) -> None:
    """Make CURVE key pairs for the world and the planner, to run them on two machines with
    every socket authenticated and encrypted (ZeroMQ CURVE).

    Writes FOLDER/world/ (world.key_secret, world.key, planners/planner.key: the planners the
    world accepts) and FOLDER/planner/ (planner.key_secret, planner.key, world.key: the world
    the planner trusts; viewers/: other diagnostics subscribers). Secret keys are mode 0600.
    Copy FOLDER/planner to the planner's machine and FOLDER/world to the world's, then start
    `m3p2i-server --host 0.0.0.0 --keys FOLDER` and `m3p2i-planner --host WORLD --keys FOLDER`.
    Another planner: `m3p2i keys OTHER`, copy OTHER/planner/planner.key into
    FOLDER/world/planners/ (under a name of its own) and FOLDER/world/world.key over
    OTHER/planner/world.key; the world reads its allow list when it starts."""
    from m3p2i.keys import make_keys

    try:
        written = make_keys(folder)
    except ConfigError as exc:
        usage_error(str(exc))
    for path in written:
        typer.echo(f"wrote {path} ({oct(path.stat().st_mode & 0o777)[2:]})")
    typer.echo(
        f"world machine: {folder / 'world'} (keep world.key_secret there only); "
        f"planner machine: {folder / 'planner'}"
    )


@app.command("list")
def list_files(
    kind: str = typer.Argument(
        "scenarios", help="What to list: scenarios, objectives, bench or robots."
    ),
) -> None:
    """List the scenarios (or objective, bench or robot files) folder by folder in lookup order:
    the folders of M3P2I_SCENARIOS, ./configs/scenarios, then the shipped ones (robots: the
    robots folders beside them, then the shipped robots). Where two folders
    have a file of the same name, the earlier one is used, and both lines say so."""
    if kind not in KINDS:
        usage_error(f"cannot list {kind!r}; one of: {', '.join(KINDS)}")
    found = entries(kind)
    # a used file -> the first file of its name that it shadows
    shadowed = {}
    for e in found:
        if e.shadowed_by is not None:
            shadowed.setdefault(e.shadowed_by, e)
    for folder in search_folders(kind):
        if not folder.path.is_dir():
            if folder.origin == ENV_VAR:  # the user named it: a typo must not go unnoticed
                typer.echo(f"{folder}: not a folder")
            continue
        typer.echo(f"{folder}:")
        for e in (e for e in found if e.folder == folder):
            note = ""
            if e.shadowed_by is not None:
                note = f"[not used: {shown(e.shadowed_by)} comes first] "
            elif e.path in shadowed:
                other = shadowed[e.path]
                note = (
                    f"[shadows the shipped {e.name}] "
                    if other.folder.origin == "shipped"
                    else f"[shadows {shown(other.path)}] "
                )
            typer.echo(f"  {e.name:24s} {note}{_description(e, kind)}".rstrip())
    if kind == "robots" and registered():
        typer.echo("registered in Python:")
        for name, spec in sorted(registered().items()):
            typer.echo(f"  {name:24s} {spec.description}".rstrip())


def _description(entry: Entry, kind: str) -> str:
    """A file's one-line description; for a scenario or a robot, whether it loads."""
    try:
        if kind == "scenarios":
            return load_scenario(entry.path).description
        if kind == "robots":
            return load_robot(entry.path).description
        return str(load_yaml(entry.path).get("description", ""))
    except ConfigError as exc:
        return f"(invalid: {exc})"


@app.command("new")
def new(
    name: str = typer.Argument(..., help="Name of the new scenario: the file NAME.yaml."),
    source: str = typer.Option(
        ..., "--from", help="Scenario to copy: a name (m3p2i list) or a YAML path."
    ),
) -> None:
    """Write a copy of scenario SOURCE, named NAME, into your scenario folder (the first of
    M3P2I_SCENARIOS, else ./configs/scenarios) to start from; never overwrites a file."""
    try:
        made = new_scenario(name, source)
    except ConfigError as exc:
        usage_error(str(exc))
    typer.echo(f"wrote {shown(made.path)}, a copy of {shown(made.source)}")
    for e in entries("scenarios"):
        if e.shadowed_by == made.path:
            typer.echo(
                f"it shadows {shown(e.path)}"
                + (" (shipped)" if e.folder.origin == "shipped" else "")
            )
    typer.echo(f"edit it, then: m3p2i run {name}")


def _episode_seconds(value: float | None) -> float | None:
    """``--timeout`` of ``m3p2i tune``: a finite number of seconds > 0 (or not given)."""
    # NaN fails both comparisons, so it is refused with the negative numbers and inf
    if value is not None and not 0 < value < float("inf"):
        raise typer.BadParameter(f"{value:g}: expected a finite number of seconds > 0")
    return value


@app.command("tune")
def tune(
    target: str = typer.Argument(
        ...,
        help="What to tune: a scenario (name or path; lock-step), a bench case name "
        "(m3p2i list bench), or BENCH:CASE.",
    ),
    space: Path = typer.Option(
        ..., "--space", help="Search space: a YAML file of scenario keys (docs/tune.md)."
    ),
    trials: int = typer.Option(
        20, "--trials", min=1, help="Study trials in all (a rerun resumes to this count)."
    ),
    seeds: str = typer.Option("0-3", "--seeds", help="Training seeds of every trial: A-B."),
    holdout: str | None = typer.Option(
        None, "--holdout", help="Held-out seeds (C-D) for the tuned overlay against the original."
    ),
    out: Path = typer.Option(..., "--out", help="Output folder; rerun with it to resume."),
    workers: int = typer.Option(
        1, min=0, help="Seeds at once, each a server + planner pair (0: one per core)."
    ),
    sampler_seed: int = typer.Option(
        0, min=0, help="Seed of the TPE sampler: same seed, same study."
    ),
    timeout: float | None = typer.Option(
        None,
        callback=_episode_seconds,
        help="Wall-clock seconds per episode, > 0 (default: the bench file's, else 600).",
    ),
    ray: bool = typer.Option(
        False, "--ray", help="Run the episodes as Ray tasks on a local instance of --workers CPUs."
    ),
    ray_address: str | None = typer.Option(None, help="Run them on the Ray cluster there."),
    cpus_per_trial: int = typer.Option(1, min=1, help="With Ray: CPUs each episode declares."),
) -> None:
    """Find a scenario's parameters: an Optuna study (TPE) over the keys of a space file, each
    trial a bench run on the training seeds, hopeless trials pruned; resumable (OUT/study.db).
    Writes OUT/overlay.yaml (base: the original plus the tuned keys, for m3p2i run) and
    OUT/report.md (history, importances, the best trial per seed, and the held-out seeds'
    success of the tuned overlay beside the original, with Wilson intervals)."""
    terminate_as_interrupt()
    from m3p2i.tune import run_tune

    run_tune(
        target,
        space,
        trials,
        seeds,
        holdout,
        out,
        workers,
        sampler_seed,
        timeout,
        ray,
        ray_address,
        cpus_per_trial,
    )


flow_help(app)  # the docstrings above as paragraphs that rich rewraps to the terminal

if __name__ == "__main__":
    app()
