"""Scripted paths (``world.disturbances[].path``, server/disturbances.py; docs/scenarios.md):
where the object is before, during and after its path, and the ``disturbance`` events a path
logs: one when it starts moving and, without ``loop``, one when it reaches its last waypoint."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from server.world import SimWorld
from shared.scenario import SCENARIO_DIR, parse_scenario


def _world(path: dict) -> SimWorld:
    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["world"]["disturbances"] = [{"path": {"object": "pillar", **path}}]
    return SimWorld(parse_scenario(raw, "x.yaml"))


def _run(world: SimWorld, steps: int) -> list[tuple]:
    out = []
    for _ in range(steps):
        world.step(np.zeros(2))
        out.append(world.data.body("pillar").xpos.copy())
    return out


def test_a_path_logs_its_start_and_its_end_and_stays_at_the_last_waypoint():
    world = _world(
        {"waypoints": [[0.0, 3.0, 0.2], [1.0, 3.0, 0.2]], "speed": 1.0, "start": 0.5, "loop": False}
    )
    start = world.data.body("pillar").xpos.copy()  # the object's scenario `pos`
    poses = _run(world, 50)  # 2.5 s of 0.05 s steps
    # before `start` it stays at its own pos; from `start` on it is on the waypoints
    np.testing.assert_allclose(poses[8], start)  # after the step at t = 0.40
    np.testing.assert_allclose(poses[10], [0.0, 3.0, 0.2])  # the step at t = 0.50: first waypoint
    np.testing.assert_allclose(poses[49], [1.0, 3.0, 0.2])  # after the last: stays there
    events = [
        (e["object"], round(e["time"], 2), e["path"], e["pos"]) for e in world.events if "path" in e
    ]
    assert events == [
        ("pillar", 0.5, "start", [0.0, 3.0, 0.2]),
        ("pillar", 1.5, "end", [1.0, 3.0, 0.2]),
    ]


def test_a_looping_path_logs_its_start_once_and_no_event_per_step():
    world = _world({"waypoints": [[0.0, 3.0, 0.2], [0.5, 3.0, 0.2]], "speed": 1.0})
    _run(world, 60)  # three laps
    assert [(e["path"], e["time"]) for e in world.events] == [("start", 0.0)]


@pytest.mark.parametrize("loop", [False, True])
def test_a_reset_logs_the_path_again(loop):
    world = _world({"waypoints": [[0.0, 3.0, 0.2], [0.2, 3.0, 0.2]], "speed": 1.0, "loop": loop})
    _run(world, 10)
    world.events.clear()
    world.reset()
    _run(world, 10)
    assert [e["path"] for e in world.events] == (["start"] if loop else ["start", "end"])
