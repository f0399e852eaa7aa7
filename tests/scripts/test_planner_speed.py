"""scripts.measure.planner_speed (scripts/benchmark.py's measurement): one case really runs the
controller closed loop and the three bare rollouts, and its row holds every figure the tables
and docs/speed.md read (what it measures is timing, not tested here)."""

from __future__ import annotations

import pytest
import torch

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
    # the rest replayed: every phase ran again, the rollout replaced by a copy of its result
    assert set(row["phases_replayed_ms"]) == set(phases)
    assert ("map_update_ms" in row) == has_map
    assert (row["threads"], row["backend"], row["device"]) == (1, "mujoco", "cpu")


def test_a_replayed_rollout_is_rolled_out_once_per_shape():
    calls = []

    class Engine:
        device = "cpu"

        def sensors(self, x0, control, mocap_path=None):
            calls.append(control.shape)
            return torch.full((*control.shape[:2], 4), float(len(calls)))

    replayed = planner_speed._Replayed(Engine())
    first = replayed.sensors(None, torch.zeros(10, 5, 2))
    again = replayed.sensors(None, torch.ones(10, 5, 2))
    assert calls == [(10, 5, 2)] and torch.equal(first, again)
    fewer = replayed.sensors(None, torch.zeros(6, 5, 2))  # the task layer switched modes
    assert calls == [(10, 5, 2), (6, 5, 2)] and fewer.shape == (6, 5, 4)
    assert replayed.device == "cpu"  # the rest is the wrapped backend's
