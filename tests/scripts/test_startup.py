"""scripts/startup.py: a cold start of both processes is timed, and the planner says how its own
start-up was spent (its log's ``start-up:`` line, planner_client.phases.STARTUP). The figures
themselves are timing, not tested here."""

from __future__ import annotations

import pytest

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
