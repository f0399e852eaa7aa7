"""Battery navigation end to end (thesis 4.2): active inference over location and battery."""

import numpy as np
import pytest

from server.episode_log import read_log
from tests.helpers import free_port_block, start_planner, start_server, stop

pytestmark = pytest.mark.slow

CHARGER = np.array([1.5, 3.0])


def _run(scenario, tmp_path):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server(scenario, port, log)
    planner = start_planner(scenario, port)
    try:
        out, _ = server.communicate(timeout=300)
        planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode == 0, out
    records = read_log(log)
    steps = [r for r in records if r["kind"] == "step"]
    actions = [(r["time"], r["action"]) for r in records if r.get("what") == "action"]
    return records[-1], steps, actions


def _charger_distance(steps):
    return np.array([np.linalg.norm(np.array(s["qpos"][:2]) - CHARGER) for s in steps])


def test_enough_battery_goes_straight_to_the_goal(tmp_path):
    summary, steps, actions = _run("battery_enough", tmp_path)
    assert summary["status"] == "success"
    # the world's success test may end the episode before the next AIP tick reports idle
    assert [a for _, a in actions] in (["move_to"], ["move_to", "idle"])
    assert _charger_distance(steps).min() > 1.0, "visited the charger without need"


def test_low_battery_recharges_first_then_reaches_the_goal(tmp_path):
    summary, steps, actions = _run("battery_recharge", tmp_path)
    assert summary["status"] == "success"
    names = [a for _, a in actions]
    assert names[:2] == ["go_recharge", "move_to"] and set(names[2:]) <= {"idle"}
    switch = actions[1][0]
    battery = np.array([s["extras"]["battery"] for s in steps])
    times = np.array([s["time"] for s in steps])
    at_charger = _charger_distance(steps) <= 0.5
    assert at_charger[times < switch].any(), "never reached the charger before moving on"
    charging = at_charger & (times < switch)
    first = np.argmax(charging)
    assert battery[times < switch][-1] > battery[first] + 1.0, "did not recharge"
    assert not at_charger[-1]
