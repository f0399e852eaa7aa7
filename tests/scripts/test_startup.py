"""scripts/startup.py: a cold start of both processes is timed, and the planner says how its own
start-up was spent (its log's ``start-up:`` line, planner_client.phases.STARTUP). The figures
themselves are timing, not tested here."""

from __future__ import annotations

import gc
import importlib
import signal
import threading
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from scripts import startup
from shared.cli_common import collector_back


@pytest.mark.slow
def test_a_cold_start_reports_the_planners_phases(tmp_path):
    once = startup.measure_once("navigation", tmp_path)
    assert set(startup.PHASES[1:]) <= set(once)
    spent = sum(once[p] for p in startup.PHASES[1:])
    # the phases run inside the planner's process, within its start -> first command
    assert all(once[p] >= 0 for p in startup.PHASES[1:]) and 0 < spent < once["planner"]
    assert once["server"] > 0


def test_a_planner_log_without_the_line_is_named(tmp_path):
    log = tmp_path / "planner.log"
    log.write_text("INFO m3p2i.planner: connected\n")
    with pytest.raises(RuntimeError, match="start-up"):
        startup._planner_phases(log)


def test_the_phases_are_awaited_when_the_planner_logs_them_after_the_worlds_step(tmp_path):
    """On a busy machine the planner's ``start-up:`` line may come after the world logged the
    step its command made; the measurement waits for it instead of stopping the planner first
    (seen under load: "no 'start-up:' line")."""
    log = tmp_path / "planner.log"
    log.write_text("INFO m3p2i.planner: connected\n")
    running = SimpleNamespace(poll=lambda: None)
    late = threading.Timer(
        0.3, lambda: log.write_text(log.read_text() + "INFO start-up: imports 1.1 s, build 0.2 s\n")
    )
    late.start()
    try:
        assert startup._wait_for_phases(log, running, timeout=30) == {
            "imports": 1.1,
            "build": 0.2,
        }
    finally:
        late.cancel()
    log.write_text("INFO m3p2i.planner: connected\n")
    with pytest.raises(RuntimeError, match="no 'start-up:' line"):  # ended without it
        startup._wait_for_phases(log, SimpleNamespace(poll=lambda: 1), timeout=30)


@pytest.mark.parametrize("process", ["server", "planner_client"])
def test_a_process_starts_without_the_collector_and_runs_with_it(monkeypatch, process):
    """Each entry point imports and builds with the garbage collector off; its CLI turns it back
    on once built (after freezing what start-up made), so no loop runs without it."""
    monkeypatch.setenv("MUJOCO_GL", "disable")  # the planner's main() sets both when unset
    monkeypatch.setenv("TORCH_DEVICE_BACKEND_AUTOLOAD", "0")
    entry = importlib.import_module(f"{process}.__main__")
    seen = {}

    def cli(prog_name: str) -> None:  # the CLI up to its build, then what its loop finds
        seen["start-up"] = gc.isenabled()
        collector_back()
        seen["loop"] = gc.isenabled()

    monkeypatch.setattr(importlib.import_module(f"{process}.cli"), "app", cli)
    frozen = gc.get_freeze_count()
    try:
        entry.main()
        assert seen == {"start-up": False, "loop": True}
        assert gc.get_freeze_count() > frozen
    finally:
        gc.unfreeze()
        gc.enable()


def test_an_in_process_caller_keeps_its_collector():
    frozen = gc.get_freeze_count()
    collector_back()
    assert gc.isenabled() and gc.get_freeze_count() == frozen


def _stub_world(*args, **kwargs):
    from server.interface import WorldError

    def run():
        raise WorldError(f"collector on: {gc.isenabled()}")

    return SimpleNamespace(run=run, interrupt=None, log=SimpleNamespace(path="-"), viewer=None)


def _stub_planner(*args, **kwargs):
    def run():
        raise RuntimeError(f"collector on: {gc.isenabled()}")

    return SimpleNamespace(run=run, close=lambda: None)


@pytest.mark.parametrize(
    "cli, builder, stub, args",
    [
        ("server.cli", "server.cli.WorldServer", _stub_world, ["--log", "episode.jsonl"]),
        ("planner_client.cli", "planner_client.build.build_client", _stub_planner, []),
    ],
)
def test_each_cli_runs_its_loop_with_the_collector_on(
    monkeypatch, tmp_path, cli, builder, stub, args
):
    """The CLI as its entry point calls it (collector off): by the time its loop runs (a stub
    that reports what it finds), the collector is on again."""
    monkeypatch.setattr(builder, stub)
    monkeypatch.setattr(signal, "signal", lambda *a: None)  # the world's: not this process's
    monkeypatch.chdir(tmp_path)
    gc.disable()
    try:
        app = importlib.import_module(cli).app
        result = CliRunner().invoke(app, ["--scenario", "navigation", *args])
    finally:
        gc.unfreeze()
        gc.enable()
    assert "collector on: True" in result.output, result.output
