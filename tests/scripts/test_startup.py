"""scripts/startup.py: a cold start of both processes is timed, and the planner says how its own
start-up was spent (its log's ``start-up:`` line, planner_client.phases.STARTUP). The figures
themselves are timing, not tested here."""

from __future__ import annotations

import gc

import pytest

from planner_client import cli
from planner_client.__main__ import main
from scripts import startup


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


def test_the_planner_starts_without_the_collector_and_plans_with_it(monkeypatch):
    """The entry point imports and builds with the garbage collector off; the CLI turns it back
    on once built (after freezing what start-up made), so the control loop never runs without."""
    monkeypatch.setenv("MUJOCO_GL", "disable")  # main() sets both when unset: restored after
    monkeypatch.setenv("TORCH_DEVICE_BACKEND_AUTOLOAD", "0")
    seen = {}

    def planner(prog_name: str) -> None:  # the CLI up to its build, then the loop's check
        seen["start-up"] = gc.isenabled()
        cli._collector_back()
        seen["loop"] = gc.isenabled()

    monkeypatch.setattr(cli, "app", planner)
    frozen = gc.get_freeze_count()
    try:
        main()
        assert seen == {"start-up": False, "loop": True}
        assert gc.get_freeze_count() > frozen
    finally:
        gc.unfreeze()
        gc.enable()


def test_an_in_process_planner_keeps_its_collector():
    frozen = gc.get_freeze_count()
    cli._collector_back()
    assert gc.isenabled() and gc.get_freeze_count() == frozen
