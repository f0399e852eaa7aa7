"""scripts.measure.planner_speed (scripts/benchmark.py's measurement): one case really runs the
controller closed loop and the three bare rollouts, and its row holds every figure the tables
and docs/speed.md read (what it measures is timing, not tested here)."""

from __future__ import annotations

import pytest

from scripts.measure import planner_speed
from shared.scenario import load_scenario

TIMES = ("iteration_ms", "rollout_ms", "own_rollout_ms", "sensor_rollout_ms")
RATIOS = ("ratio_to_rollout", "ratio_to_own_rollout", "ratio_to_sensor_rollout")


@pytest.mark.parametrize("name, has_map", [("navigation", False), ("navigation_seen", True)])
def test_a_case_times_the_controller_and_its_bare_rollouts(name, has_map):
    row = planner_speed.measure(load_scenario(name), iterations=20, nthread=1, rounds=2)
    assert (row["scenario"], row["samples"], row["horizon"]) == (name, 200, 5)
    assert (row["planning_step"], row["world_step"]) == pytest.approx((0.15, 0.05))
    assert all(row[k] > 0 for k in TIMES + RATIOS), row
    assert row["hz"] == pytest.approx(1e3 / row["iteration_ms"], rel=1e-3)
    phases = row["phases_ms"]
    assert {"mirror", "sampling", "rollout", "costs", "update", "command"} <= set(phases)
    assert sum(phases.values()) > 0.5 * row["iteration_ms"]  # medians: about the whole
    assert ("map_update_ms" in row) == has_map
    assert (row["threads"], row["backend"], row["device"]) == (1, "mujoco", "cpu")
