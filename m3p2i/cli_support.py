"""What several ``m3p2i`` commands share: a scenario checked by both processes before anything
starts, the planner's ``--plugins`` as the processes need them, and SIGTERM taken as Ctrl-C."""

from __future__ import annotations

import signal
from pathlib import Path

import typer

from m3p2i.process_checks import scenario_errors
from shared.config import ConfigError
from shared.scenario import find_scenario, load_scenario


def load_or_exit(scenario: str, plugins: tuple[str, ...] = ()):
    """The scenario, checked by both processes before either starts (the planner with its
    ``--plugins``); or exit 2 printing every error of the file (file, key path, value,
    expected)."""
    try:
        path = find_scenario(scenario)
    except ConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    errors = scenario_errors(path, plugins)
    for message in errors:
        typer.echo(f"error: {message}", err=True)
    if errors:
        typer.echo(f"{path}: {len(errors)} error{'s' if len(errors) > 1 else ''}", err=True)
        raise typer.Exit(2)
    return load_scenario(path)


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
