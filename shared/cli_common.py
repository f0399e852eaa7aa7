"""What the three command-line programs share: the options they have in common (declared once
here, as ``Annotated`` types; a command sets only the default), help text that typer's rich
output can rewrap, logging, the one-line summaries and error lines they print, the garbage
collector turned back on after a process's start-up, and the watch that stops a process whose
launcher died."""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.logging import RichHandler

from shared.config import ConfigError, deprecated
from shared.protocol import MAX_SEED
from shared.scenario.faults import PROFILES

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

MODES = ("lockstep", "realtime")
Mode = Annotated[
    str,
    typer.Option(
        "--mode",
        help="lockstep: the world steps only when the command for its latest state "
        "arrives (deterministic). realtime: it steps on the wall clock, playing the newest "
        "command's plan.",
    ),
]


def mode_conflicts(
    mode: str, plan_every: int = 1, max_rate: float = 0.0, realtime_factor: float = 1.0
) -> list[tuple[str, str, object, str]]:
    """The options that mean nothing in ``mode``, each as ``(key, why, value, expected)`` (the
    bench names the key, ``m3p2i run`` and ``m3p2i-server`` its flag): a combination that
    would be silently ignored is refused instead."""
    if mode not in MODES:
        return [("mode", "unknown mode", mode, " or ".join(MODES))]
    out: list[tuple[str, str, object, str]] = []
    if max_rate and mode != "realtime":
        out.append(
            (
                "max_rate",
                "only a real-time world lets a planner fall behind",
                max_rate,
                "mode: realtime (lock-step: plan_every)",
            )
        )
    if realtime_factor != 1.0 and mode != "realtime":
        out.append(
            (
                "realtime_factor",
                "only a real-time world has a wall clock to follow",
                realtime_factor,
                "mode: realtime",
            )
        )
    if plan_every > 1 and mode != "lockstep":
        out.append(
            (
                "plan_every",
                "only a lock-step world plays a plan for a set number of steps",
                plan_every,
                "1 with mode: realtime",
            )
        )
    return out


PlanEvery = Annotated[
    int,
    typer.Option(
        "--plan-every",
        min=1,
        help="lockstep: world steps played per command (its plan's knots by "
        "time). K > 1 emulates, repeatably, a planner K times slower than a real-time world.",
    ),
]
RealtimeFactor = Annotated[
    float,
    typer.Option(
        "--realtime-factor",
        min=0.01,
        max=100.0,
        help="realtime: simulated seconds per wall second; 0.5 runs "
        "the world at half speed, so every planner rate counts double against it.",
    ),
]
Faults = Annotated[
    str | None,
    typer.Option(
        "--faults",
        help="Simulated faults for the world, to rehearse a robot "
        f"(docs/faults.md): a fault profile ({', '.join(PROFILES)}) or a YAML file of faults: keys "
        "(delays, noise, dropped states, withheld velocities, control period, model mismatch, "
        "binary gripper). Replaces the scenario's own faults: section. Only the world is told: the "
        "planner keeps the nominal model (m3p2i run --compensate declares the delays to it). "
        "lockstep: faults drawn from --seed, delays in world steps (repeatable); realtime: "
        "wall-clock delays.",
    ),
]
OldFaults = Annotated[str | None, typer.Option("--hardware", hidden=True)]  # deprecated
MeasureDelays = Annotated[
    bool,
    typer.Option(
        "--measure-delays",
        help="The planner measures the robot's delays online "
        "(planner.delays.measure): the state delay from the lag the world reports, the actuation "
        "delay from how the robot answers the controls sent; declared delays stand until then "
        "(docs/faults.md).",
    ),
]
Window = Annotated[
    bool,
    typer.Option(
        "--window/--no-window",
        help="Open MuJoCo's own viewer window on "
        "the world's machine (needs a display); drag objects in it to disturb the world.",
    ),
]
OldWindow = Annotated[bool, typer.Option("--viewer", hidden=True)]  # deprecated
OldMeasureDelays = Annotated[bool, typer.Option("--estimate-delays", hidden=True)]  # deprecated


def renamed(value, old_value, new: str, old: str, default):
    """An option's ``value``, or the one given under its old name ``old`` (``--hardware``,
    ``--viewer``), which warns once, naming ``new``; both given: a usage error."""
    if old_value == default:
        return value
    if value != default:
        raise typer.BadParameter(f"both {new} and {old} (its old name) given", param_hint=old)
    deprecated(old, f"write {new}")
    return old_value


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
Plugins = Annotated[
    list[str] | None,
    typer.Option(
        "--plugins",
        help="A Python module of your own cost terms for the planner to import (repeatable): "
        "a .py file or an importable module name, besides the scenario's plugins: "
        "(docs/cost_terms.md). Only the planner imports it.",
    ),
]


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
    Each takes SIGTERM as Ctrl-C (:func:`signals_as_ctrl_c`; the world's own handler): the
    world ends its episode with its summary, the planner prints its statistics, the view
    closes its page and its recording. Not SIGINT: a process started
    in the background inherits SIGINT ignored. A daemon thread checks every ``every`` s, the
    first time ``every`` s after this call: call it just before the code that handles Ctrl-C.
    Without ``parent`` nothing is watched."""
    if parent is None:
        return

    def watch() -> None:
        time.sleep(every)  # first: the caller is then past this call, inside its Ctrl-C path
        while os.getppid() == parent:
            time.sleep(every)
        logging.getLogger("m3p2i").warning("launcher %d is gone: stopping as on Ctrl-C", parent)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


@contextlib.contextmanager
def signals_as_ctrl_c() -> Iterator[None]:
    """Inside the block, SIGINT and SIGTERM raise KeyboardInterrupt in the main thread, as
    Ctrl-C does in a terminal, whatever the process inherited (a background start ignores
    SIGINT; SIGTERM's default ends the process on the spot, before it says how it did); the
    handlers before it are back after it. Run in another thread (a command invoked in-process,
    as tests do), it changes nothing: a process's signals are its main thread's to take."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


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


def default_run_dir(scenario: str) -> Path:
    """``runs/<scenario>-<YYYYmmdd-HHMMSS>`` under the current directory."""
    return Path("runs") / f"{scenario}-{time.strftime('%Y%m%d-%H%M%S')}"


def summary_line(status: str, sim_time: float, measures: dict[str, float]) -> str:
    """One line for the end of an episode: outcome, simulated time, measures, planner Hz."""
    parts = [f"{status}", f"time {sim_time:.2f} s"]
    for k, v in measures.items():
        if k == "planner_hz":
            continue
        unit = " m" if k.startswith("distance") else ""
        parts.append(f"final {k} {v:.3f}{unit}")
    if "planner_hz" in measures:
        parts.append(f"planner {measures['planner_hz']:.1f} Hz")
    return ", ".join(parts)


ERROR_PREFIX = "error: "


def print_errors(errors, err: bool = True) -> None:
    """Each error on its own ``error: ...`` line(s), as ``m3p2i`` reads them back from the
    processes' ``--check``."""
    for e in errors:
        print(f"{ERROR_PREFIX}{e}", file=sys.stderr if err else sys.stdout)


def error_blocks(text: str) -> list[str]:
    """The messages :func:`print_errors` wrote into ``text`` (a message may span lines)."""
    blocks: list[str] = []
    for line in text.splitlines():
        if line.startswith(ERROR_PREFIX):
            blocks.append(line[len(ERROR_PREFIX) :])
        elif blocks and line:
            blocks[-1] += "\n" + line
    return blocks
