"""What several ``m3p2i`` commands share: a scenario checked by both processes before anything
starts, ``--faults``, ``--compensate`` and ``--keys`` checked likewise, the planner's
``--plugins`` as the processes need them, and SIGTERM taken as Ctrl-C."""

from __future__ import annotations

import inspect
import signal
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from m3p2i.process_checks import scenario_errors
from shared.cli_common import SCENARIO_HELP
from shared.config import ConfigError
from shared.protocol import MAX_SEED
from shared.scenario import find_scenario, load_scenario

# --- options of m3p2i's own commands ------------------------------------------------------

ScenarioArgument = Annotated[str, typer.Argument(help=SCENARIO_HELP)]
RunDir = Annotated[
    Path | None,
    typer.Option("--run-dir", help="Where the episode's logs go (default runs/<scenario>-<time>)."),
]
Timeout = Annotated[
    float,
    typer.Option("--timeout", min=0.001, help="Wall-clock seconds before the run is abandoned."),
]
Seed = Annotated[
    int,
    typer.Option(
        "--seed",
        min=0,
        max=MAX_SEED,
        help="Seed of the episode: the world's randomised start (world.randomize) and the "
        "planner's sampling.",
    ),
]


# a video (m3p2i record, python -m m3p2i.video)
VIDEO_FORMATS = (".gif", ".mp4")
Width = Annotated[int, typer.Option(min=16, max=4096, help="Frame width in pixels.")]
Height = Annotated[int, typer.Option(min=16, max=4096, help="Frame height in pixels.")]
Fps = Annotated[float, typer.Option(min=0.1, max=240, help="Frames per second of the video.")]
Speed = Annotated[
    float, typer.Option(min=0.01, max=100, help="Simulated seconds per video second.")
]

# --- help text ------------------------------------------------------------------------------


def flowing(text: str) -> str:
    """``text`` dedented, each paragraph on one line (paragraphs stay apart by a blank line).

    Typer's rich help rewraps only a command's first paragraph and keeps the hard line breaks
    of the others, which then break sentences wherever the source lines ended."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs if p.strip())


def flow_help(app: typer.Typer) -> None:
    """Every help text of ``app`` (its own and each command's, from ``help=`` or the
    docstring) as :func:`flowing` paragraphs. Call it once the commands are registered."""
    if isinstance(app.info.help, str):
        app.info.help = flowing(app.info.help)
    for command in app.registered_commands:
        text = command.help or inspect.getdoc(command.callback)
        if text:
            command.help = flowing(text)


def usage_error(message: str) -> NoReturn:
    """``error: message`` on stderr and exit 2: an option or file the command cannot use,
    before anything starts."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def load_or_exit(scenario: str, plugins: tuple[str, ...] = ()):
    """The scenario, checked by both processes before either starts (the planner with its
    ``--plugins``); or exit 2 printing every error of the file (file, key path, value,
    expected)."""
    try:
        path = find_scenario(scenario)
    except ConfigError as exc:
        usage_error(str(exc))
    errors = scenario_errors(path, plugins)
    for message in errors:
        typer.echo(f"error: {message}", err=True)
    if errors:
        typer.echo(f"{path}: {len(errors)} error{'s' if len(errors) > 1 else ''}", err=True)
        raise typer.Exit(2)
    return load_scenario(path)


def scenarios_or_exit(names: list[str], teams: bool = True) -> list:
    """Each scenario of ``names`` as :func:`load_or_exit` loads it (exit 2 at the first that is
    not sound); ``teams``: whether a scenario of several robots is taken (exit 2 if not)."""
    scenarios = []
    for name in names:
        sc = load_or_exit(name)
        if sc.team and not teams:
            usage_error(
                f"{name}: a scenario of {len(sc.team)} robots starts a planner per robot; "
                "this measures one (expected a scenario of one robot)"
            )
        scenarios.append(sc)
    return scenarios


def plugin_args(plugins: list[str] | None) -> tuple[str, ...]:
    """``--plugins`` for the planner processes: a file as an absolute path (they may run in
    another folder), a module name as given."""
    return tuple(str(Path(p).absolute()) if Path(p).is_file() else p for p in plugins or ())


def terminate_as_interrupt() -> None:
    """SIGTERM (``kill``, a job scheduler, a CI time-out) as Ctrl-C: Python's default would end
    the process on the spot, leaving the episodes' server and planner processes running; as a
    KeyboardInterrupt it takes the Ctrl-C path, which stops them and keeps the finished rows."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)


def faults_or_exit(spec: str) -> str:
    """``--faults`` checked before either process starts; what the server is passed (a
    profile's name, or the file's absolute path: the server may run elsewhere than here)."""
    from server.options import load_faults
    from shared.scenario.faults import PROFILES

    try:
        load_faults(spec)
    except ConfigError as exc:
        usage_error(str(exc))
    return spec if spec in PROFILES else str(Path(spec).resolve())


def declared_delays_or_exit(sc, faults: str | None) -> tuple[float, float]:
    """``--compensate``: the (actuation, state) delays in ms of ``--faults``, else of the
    scenario's faults: section, for the planner to declare; exit 2 when there are none."""
    from server.options import load_faults

    delays = (load_faults(faults) if faults else sc.faults).delays
    if delays is None:
        usage_error(
            "--compensate: no delay to compensate (give --faults PROFILE, or a "
            "scenario whose faults: section sets actuation_delay_ms or state_delay_ms)"
        )
    return delays


def keys_or_exit(keys: Path | None, world: bool = True):
    """Both sides' keys checked before either process starts (a bad key folder is one clear
    error here, not two processes failing); the planner's (tools use its pair), or None.
    ``world=False``: a tool that starts no world (m3p2i view), which may run on a planner
    machine holding only ``DIR/planner``, needs and checks only the planner's keys."""
    if keys is None:
        return None
    from planner_client.keys import load_planner_keys
    from server.keys import load_world_keys

    try:
        if world:
            load_world_keys(keys)
        return load_planner_keys(keys)
    except ConfigError as exc:
        usage_error(str(exc))
