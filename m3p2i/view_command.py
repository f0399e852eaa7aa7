"""``m3p2i view``: the browser view of a live episode (beside a running world and planner) or
of a logged one (``--log``): its options and the command."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from typing import Annotated

import typer

from m3p2i.cli_support import keys_or_exit, load_or_exit, usage_error
from planner_client.signals import signals_as_ctrl_c
from shared.cli_common import Host, Keys, ParentPid, Port, stop_with_parent
from shared.config import ConfigError
from shared.endpoints import DEFAULT_HOST, DEFAULT_PORT

ViewScenario = Annotated[
    str | None,
    typer.Argument(
        help="Scenario the world runs (name or path), for a live view; leave out with --log."
    ),
]
ReplayLog = Annotated[
    Path | None,
    typer.Option(
        help="Replay this episode log (or run folder) instead: a time slider, the actions, the "
        "metrics."
    ),
]
PagePort = Annotated[
    int, typer.Option(min=1, max=65535, help="Port of the page (the next free one if taken).")
]
Public = Annotated[
    bool,
    typer.Option(
        "--public",
        help="Serve the page on every network interface, not only loopback, to watch only: its "
        "pause, reset and move controls are off (see --public-controls).",
    ),
]
PublicControls = Annotated[
    bool,
    typer.Option(
        "--public-controls",
        help="With --public: keep the controls, so that anyone who reaches the page can pause, "
        "reset and disturb the world (with the planner's keys): only on a network you trust.",
    ),
]
Record = Annotated[
    Path | None,
    typer.Option(
        help="Live: also write the planner's diagnostics (trajectories, mode weights) to this "
        "file, for a replay (as diagnostics.jsonl beside the episode log)."
    ),
]
Duration = Annotated[
    float | None,
    typer.Option(min=0.001, help="Stop after this many seconds (default: until Ctrl-C)."),
]
ReplayAfter = Annotated[
    Path | None,
    typer.Option(
        help="Live: on SIGUSR1 (what `m3p2i run --view` sends once its episode is over) the "
        "same page replays this episode log or run folder, until Ctrl-C."
    ),
]


def view(
    scenario: ViewScenario = None,
    log: ReplayLog = None,
    host: Host = DEFAULT_HOST,
    port: Port = DEFAULT_PORT,
    view_port: PagePort = 8080,
    public: Public = False,
    public_controls: PublicControls = False,
    record: Record = None,
    duration: Duration = None,
    keys: Keys = None,
    replay_after: ReplayAfter = None,
    parent_pid: ParentPid = None,
) -> None:
    """Show a world and its planner in a browser: the scene from the scenario's model, the
    planner's best sampled trajectories coloured by mode, the executed path, the action and its
    alternatives, mode weights, rates, battery; pause, resume, reset, and drag objects to disturb
    the world. Read-only otherwise: the planner never waits for it.

    Live: `m3p2i view pick_place --port 5555` beside a running server and planner (or
    `m3p2i run pick_place --view`). Replay: `m3p2i view --log runs/pick_place-.../`."""
    from m3p2i import view as V
    from shared.endpoints import Endpoints

    if (scenario is None) == (log is None):
        usage_error("give a SCENARIO for a live view, or --log to replay an episode")
    live_only = {
        "--host": host != DEFAULT_HOST,
        "--port": port != DEFAULT_PORT,
        "--public-controls": public_controls,
        "--record": record is not None,
        "--keys": keys is not None,
        "--replay-after": replay_after is not None,
    }
    if log is not None and (given := [flag for flag, on in live_only.items() if on]):
        usage_error(
            f"{', '.join(given)}: live view only; a replay (--log) has no world to reach or record"
        )
    bind = "0.0.0.0" if public else "127.0.0.1"
    over = threading.Event()  # the episode is over: --replay-after takes the page over
    if replay_after is not None and log is None:
        signal.signal(signal.SIGUSR1, lambda *_: over.set())
    try:
        if log is not None:
            shown = _replay_or_exit(log, bind, view_port)
        else:
            shown = V.LiveView(
                load_or_exit(scenario),
                Endpoints(host, port),
                bind,
                view_port,
                record=record,
                keys=keys_or_exit(keys, world=False),
                controls=not public or public_controls,
            )
    except ImportError as exc:
        usage_error(str(exc))
    if log is None and replay_after is not None:
        shown.stop = over  # the live view serves until the episode is over
    typer.echo(f"view: {shown.url}")
    sys.stdout.flush()
    stop_with_parent(parent_pid)  # m3p2i run's page: not kept waiting by a killed launcher
    with signals_as_ctrl_c():  # a SIGTERM (the launcher's stop, the watch's) closes it as Ctrl-C
        _show(shown, duration, over, replay_after, bind, view_port)


def _replay_or_exit(log: Path, bind: str, view_port: int, server=None, code: int = 2):
    """The replay page of ``log`` (on ``server``, the live page's, when given); exit ``code``
    when it cannot be read."""
    from m3p2i import view as V

    try:
        return V.ReplayView(V.load_replay(log), bind, view_port, server=server)
    except (ConfigError, FileNotFoundError, ValueError) as exc:
        typer.echo(f"error: {'no replay of ' + str(log) + ': ' if server else ''}{exc}", err=True)
        raise typer.Exit(code) from None


def _show(shown, duration, over, replay_after, bind: str, view_port: int) -> None:
    """Serve the page for ``duration`` (or until Ctrl-C); once the episode is ``over``, the
    same page replays ``replay_after``."""
    try:
        shown.serve(duration)
        if over.is_set():
            shown.close(keep_server=True)
            shown = _replay_or_exit(replay_after, bind, view_port, server=shown.server, code=1)
            typer.echo(f"replay: {replay_after}")
            sys.stdout.flush()
            shown.serve(None)
    except KeyboardInterrupt:
        pass
    finally:
        shown.close()
