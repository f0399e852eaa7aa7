"""Start-up times: world server start to serving its first state, planner start to its first
command, measured from the episode log's wall-clock stamps.

The two processes are started one after the other (as from two terminals), so neither's start-up
slows the other's: the server first, then the planner once the server serves. The server's time
runs from its process start to the log's ``header`` record (written when its sockets are bound
and it starts publishing states); the planner's from its process start to the world's first
``step`` record (its first command applied, lock-step). Both include the Python interpreter, the
imports and the model compilation; the planner's also its handshake and first iteration. The
planner's own phases come from the ``start-up:`` line of its log (planner_client.phases.STARTUP):
imports, check (the scenario checked), build (model compiled, planner built), handshake, first
command (its first state received, planned and answered); ``python`` is the rest of the total:
the interpreter's start and the world's step after the command.

Python caches each module's compiled bytecode beside it (``__pycache__``) on first import, and a
wheel install compiles it at install; with ``PYTHONDONTWRITEBYTECODE`` set, a clone's ~110
modules are compiled from source at every start instead (some 0.2-0.3 s of the planner's). The
script therefore compiles the project's packages first, as any of those has them;
``--no-compile`` measures without (what was cached stays).

    python scripts/startup.py                        # navigation and pick_place, 5 runs each
    python scripts/startup.py -s push_pull -n 3 --json
"""

from __future__ import annotations

import compileall
import importlib.util
import json
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from m3p2i.cli_support import scenarios_or_exit
from m3p2i.launch import free_port_block, stop_processes
from server.evaluation import log_reader

SCENARIOS = ("navigation", "pick_place")
PACKAGES = ("planner_client", "server", "shared", "m3p2i")  # what the two processes import
PHASES = ("python", "imports", "check", "build", "handshake", "first command")

app = typer.Typer(add_completion=False)


def _wait_for(log: Path, kind: str, proc: subprocess.Popen, timeout: float) -> dict:
    """The first record of ``kind`` in ``log``, polled until ``timeout`` s or ``proc`` dies."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if log.is_file():
            for rec in log_reader.read_log(log):
                if rec.get("kind") == kind:
                    return rec
        if proc.poll() is not None:
            raise RuntimeError(
                f"{proc.args[2]} exited with code {proc.returncode} before a "
                f"{kind!r} record; see the logs next to {log}"
            )
        time.sleep(0.01)
    raise RuntimeError(f"no {kind!r} record in {log} within {timeout:g} s")


def measure_once(scenario: str, folder: Path, timeout: float = 60.0) -> dict[str, float]:
    """One cold start of both processes: ``{"server": s, "planner": s}``."""
    port = free_port_block()
    log = folder / "episode.jsonl"
    common = ["--scenario", scenario, "--port", str(port)]
    procs = []
    try:
        with (folder / "server.log").open("w") as out:
            start = time.time()
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "server", *common, "--log", str(log)],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            )
            server = _wait_for(log, "header", procs[0], timeout)["wall"] - start
        with (folder / "planner.log").open("w") as out:
            start = time.time()
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "planner_client", *common],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            )
            planner = _wait_for(log, "step", procs[1], timeout)["wall"] - start
        # the planner logs its phases just after sending the command the world applied: on a
        # busy machine that line may come after the world's step record, so stop after it
        phases = _wait_for_phases(folder / "planner.log", procs[1], timeout)
    finally:
        stop_processes(procs)
    return {"server": server, "planner": planner, **phases}


def _wait_for_phases(log: Path, proc: subprocess.Popen, timeout: float) -> dict[str, float]:
    """:func:`_planner_phases` of ``log`` once the line is there, polled until ``timeout`` s
    or ``proc`` ends (then its absence is the error)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        if "start-up: " in log.read_text():
            break
        time.sleep(0.01)
    return _planner_phases(log)


def _planner_phases(log: Path) -> dict[str, float]:
    """The planner's start-up phases, seconds by name, from its log's ``start-up:`` line."""
    for line in log.read_text().splitlines():
        if "start-up: " in line:
            pairs = re.findall(r"([a-z ]+) ([0-9.]+) s", line.split("start-up: ", 1)[1])
            return {name.strip(): float(sec) for name, sec in pairs}
    raise RuntimeError(f"no 'start-up:' line in {log}")


def _measured_or_exit(path: str) -> dict[str, float]:
    """:func:`measure_once` in a fresh folder, removed after; on failure the folder (the two
    processes' logs) is kept, named, and the script exits 1."""
    folder = Path(tempfile.mkdtemp(prefix="m3p2i-startup-"))
    try:
        once = measure_once(path, folder)
    except RuntimeError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    shutil.rmtree(folder, ignore_errors=True)
    return once


@app.command()
def main(
    scenario: list[str] = typer.Option(
        list(SCENARIOS), "--scenario", "-s", help="Scenario name or YAML path (repeatable)."
    ),
    runs: int = typer.Option(5, "--runs", "-n", min=1, help="Cold starts per scenario."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per scenario."),
    compile_first: bool = typer.Option(
        True, "--compile/--no-compile", help="Compile the project's bytecode before timing."
    ),
) -> None:
    """Time cold starts of the world server and the planner; print median and spread."""
    scenarios = scenarios_or_exit(scenario, teams=False)
    console = Console()
    if compile_first:
        for package in PACKAGES:
            for folder in importlib.util.find_spec(package).submodule_search_locations:
                compileall.compile_dir(folder, quiet=1)
    table = Table("scenario", "server start -> serving [s]", "planner start -> first command [s]")
    phases = Table("scenario", *PHASES, title="the planner's start-up by phase, median [s]")
    for name, sc in zip(scenario, scenarios):
        samples: dict[str, list[float]] = {}
        for i in range(runs):
            once = _measured_or_exit(sc.source)
            once["python"] = once["planner"] - sum(once.get(p, 0.0) for p in PHASES[1:])
            for side, seconds in once.items():
                samples.setdefault(side, []).append(seconds)
            if not as_json:
                console.print(f"{name}: run {i + 1}/{runs}", style="dim")
        stats = {
            side: {"median": statistics.median(v), "min": min(v), "max": max(v)}
            for side, v in samples.items()
        }
        if as_json:
            print(json.dumps({"scenario": name, "runs": runs, **stats}))
        else:
            table.add_row(
                name,
                *(
                    f"{stats[s]['median']:.2f} ({stats[s]['min']:.2f}-{stats[s]['max']:.2f})"
                    for s in ("server", "planner")
                ),
            )
            phases.add_row(name, *(f"{stats[p]['median']:.3f}" for p in PHASES))
    if not as_json:
        console.print(table)
        console.print(phases)


if __name__ == "__main__":
    app()
