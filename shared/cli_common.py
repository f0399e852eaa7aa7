"""What the three command-line programs share: the options they have in common (declared once
here, as ``Annotated`` types; a command sets only the default) and their old names, logging, the
error lines they print, the exit on a network address without keys, the garbage collector turned
back on after a process's start-up, and the watch that stops a process whose launcher died. The
options of one side alone (and of ``m3p2i``'s commands that pass them on) are that side's:
``server/options.py``, ``planner_client/options.py``; help text that typer's rich output can
rewrap is ``m3p2i/cli_support.py``'s."""

from __future__ import annotations

import gc
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.logging import RichHandler

from shared.config import ConfigError, deprecated

# --- options shared by m3p2i-server, m3p2i-planner and m3p2i's commands --------------------

SCENARIO_HELP = "Scenario name (m3p2i list) or YAML path."
ScenarioOption = Annotated[str, typer.Option("--scenario", "-s", help=SCENARIO_HELP)]

Host = Annotated[
    str,
    typer.Option(
        "--host",
        help="The world's address: the one m3p2i-server binds (loopback by default), the "
        "one the planner and the view connect to. A network address (e.g. 0.0.0.0 on the world's "
        "side) needs --keys (or, on m3p2i-server and m3p2i-planner, --insecure).",
    ),
]
LAST_FIRST_PORT = 65535 - 3  # the world's ports are PORT..PORT+3
Port = Annotated[
    int,
    typer.Option(
        "--port",
        min=1,
        max=LAST_FIRST_PORT,
        help="The world's first port: control; the state is published on PORT+1, "
        "commands arrive on PORT+2, the planner's diagnostics are on PORT+3.",
    ),
]
Keys = Annotated[
    Path | None,
    typer.Option(
        "--keys",
        help="CURVE key folder made by `m3p2i keys DIR`: every socket authenticated and "
        "encrypted. The world uses DIR/world/ (it accepts only the planners whose public keys are "
        "in DIR/world/planners/), the planner and the view DIR/planner/ (the world's public key "
        "in DIR/planner/world.key).",
    ),
]
Insecure = Annotated[
    bool,
    typer.Option(
        "--insecure",
        help="Allow a network address without --keys: anyone who reaches the ports "
        "can drive the robot. Only on an isolated, trusted network; warned at every start.",
    ),
]
Verbose = Annotated[
    bool,
    typer.Option(
        "--verbose",
        "-v",
        help="Debug messages too; m3p2i run shows both processes' output "
        "instead of writing it to log files.",
    ),
]


def renamed(value, old_value, new: str, old: str, default):
    """An option's ``value``, or the one given under its old name ``old`` (``--hardware``,
    ``--viewer``), which warns once, naming ``new``; both given: a usage error."""
    if old_value == default:
        return value
    if value != default:
        raise typer.BadParameter(f"both {new} and {old} (its old name) given", param_hint=old)
    deprecated(old, f"write {new}")
    return old_value


ParentPid = Annotated[
    int | None,
    typer.Option(
        "--parent-pid",
        min=1,
        help="Stop, as on Ctrl-C, once process PID (the launcher that started this one: "
        "m3p2i run and m3p2i bench pass their own) is no longer its parent: a launcher killed "
        "outright leaves nothing behind.",
    ),
]


def stop_with_parent(parent: int | None, every: float = 0.5) -> None:
    """With ``parent`` (``--parent-pid``), SIGTERM to this process, once, as soon as it is no
    longer ``parent``'s child: its launcher has died, even by SIGKILL, and a kept world or
    planner (``--keep-serving``, ``--keep-running``) or a live view would wait for it forever.
    Each takes SIGTERM as Ctrl-C (the planner and the view:
    :func:`planner_client.signals.signals_as_ctrl_c`; the world: its own handler): the world
    ends its episode with its summary, the planner prints its statistics, the view closes its
    page and its recording. Not SIGINT: a process started in the background inherits SIGINT
    ignored. A daemon thread checks every ``every`` s, the first time ``every`` s after this
    call: call it just before the code that handles Ctrl-C. Without ``parent`` nothing is
    watched."""
    if parent is None:
        return

    def watch() -> None:
        time.sleep(every)  # first: the caller is then past this call, inside its Ctrl-C path
        while os.getppid() == parent:
            time.sleep(every)
        logging.getLogger("m3p2i").warning("launcher %d is gone: stopping as on Ctrl-C", parent)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def collector_back() -> None:
    """Python's garbage collector on again once a process is built, after the entry point
    (``server/__main__.py``, ``planner_client/__main__.py``) started it without one: the
    imports and the build make a few hundred thousand objects and next to no garbage, and
    collecting as they went cost 0.05 s of the world's start and 0.2 s of the planner's
    (docs/speed.md). What start-up made is frozen first, so that no collection in the loop
    traverses it again; the cycles start-up left (the planner's: ~7,000 functions, cells, tuples
    and types of the imports, no arrays; under 1 MB) stay with it, as a full collection here
    would cost 0.1 s. A caller whose collector is on (in-process, tests) is left as it is."""
    if not gc.isenabled():
        gc.freeze()
        gc.enable()


def keys_or_exit(hosts: dict[str, str], keys: Path | None, insecure: bool, load, warn):
    """A process's CURVE keys, loaded with ``load`` (None without ``--keys``); exit 2 for a
    network address without keys (unless ``--insecure``: then ``warn`` is given the warning)
    or for keys that cannot be used (:func:`shared.security.keys_for_cli`)."""
    from shared.security import ExposureError, keys_for_cli  # zmq.auth: not for m3p2i

    try:
        return keys_for_cli(hosts, keys, insecure, load, warn)
    except (ExposureError, ConfigError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None


def setup_logging(verbose: bool, name: str) -> None:
    """Rich output on a terminal; plain one-line records when redirected (log files, CI),
    where rich would wrap long lines at 80 columns."""
    level = logging.DEBUG if verbose else logging.INFO
    if sys.stderr.isatty():
        logging.basicConfig(
            level=level,
            format="%(message)s",
            datefmt="[%X]",
            handlers=[RichHandler(show_path=False, markup=False)],
        )
    else:
        logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger(name).setLevel(level)


ERROR_PREFIX = "error: "


def print_errors(errors, err: bool = True) -> None:
    """Each error on its own ``error: ...`` line(s), as ``m3p2i`` reads them back from the
    processes' ``--check``."""
    for e in errors:
        print(f"{ERROR_PREFIX}{e}", file=sys.stderr if err else sys.stdout)
