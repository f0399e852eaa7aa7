"""Push, pull and hybrid push-pull end to end (paper III.B, Tables I-II): both processes in
lock-step over loopback, seed 0 for the world's randomised start and the planner's sampling."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from server.episode_log import read_log
from shared.scenario import SCENARIO_DIR
from tests.helpers import free_port_block, start_planner, start_server, stop, wait_episode

pytestmark = pytest.mark.slow

SUCTION = 2   # point_robot_suction: ctrl = (vel_x, vel_y, suction)
BOX = slice(2, 4)   # the box's x, y in qpos, after the robot's two slide joints


def _run(scenario: str, tmp_path, max_time: float | None = None, seed: int = 0):
    """One episode: (summary, steps, action events). ``max_time`` runs a copy of the scenario
    with that time-out instead of its own."""
    source = scenario
    if max_time is not None:
        raw = yaml.safe_load((SCENARIO_DIR / f"{scenario}.yaml").read_text())
        raw["episode"]["max_time"] = max_time
        source = str(tmp_path / f"{scenario}.yaml")
        (tmp_path / f"{scenario}.yaml").write_text(yaml.safe_dump(raw))
    port = free_port_block()
    log = tmp_path / f"{scenario}.jsonl"
    server = start_server(source, port, log, "--seed", str(seed))
    planner = start_planner(source, port, "--seed", str(seed))
    try:
        out = wait_episode(server, planner)
        planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode in (0, 1), out     # 1: the episode timed out
    records = read_log(log)
    steps = [r for r in records if r["kind"] == "step"]
    actions = [r["action"] for r in records if r.get("what") == "action"]
    return records[-1], steps, actions


def _suction(steps) -> np.ndarray:
    return np.array([s["ctrl"][SUCTION] for s in steps])


@pytest.fixture(scope="module")
def corner_to_corner(tmp_path_factory):
    return _run("push_pull_corner2", tmp_path_factory.mktemp("corner2"))


def test_push_reaches_the_goal_with_the_suction_off(tmp_path):
    summary, steps, _ = _run("push", tmp_path)
    assert summary["status"] == "success"
    assert summary["measures"]["distance box-goal"] <= 0.1
    assert not _suction(steps).any()


def test_pull_drags_the_box_to_the_goal_with_the_suction_on(tmp_path):
    summary, steps, _ = _run("pull", tmp_path)
    assert summary["status"] == "success"
    assert (_suction(steps) == 1.0).all()


@pytest.mark.parametrize("scenario", ["push_dynamic_obstacle", "pull_dynamic_obstacle"])
def test_push_and_pull_among_a_moving_obstacle_never_touch_it(scenario, tmp_path):
    """Table I's setting: the world moves the obstacle, the planner only sees its poses."""
    summary, steps, _ = _run(scenario, tmp_path)
    assert summary["status"] == "success"
    assert summary["metrics"]["collisions"] == 0
    mover = np.array([s["mocap_pos"][-1][:2] for s in steps])
    assert np.ptp(mover[:, 1]) > 1.0           # it did move across the way


def test_hybrid_puts_the_box_into_a_corner(tmp_path):
    summary, _, _ = _run("push_pull_corner1", tmp_path)
    assert summary["status"] == "success"


def test_hybrid_takes_the_box_from_corner_to_corner_pulling_then_pushing(corner_to_corner):
    summary, steps, _ = corner_to_corner
    assert summary["status"] == "success"
    # the executed suction follows the dominant mode: on when the box leaves its corner (pulled
    # out), off at the end (pushed into the other corner)
    box = np.array([s["qpos"][BOX] for s in steps])
    moved = np.flatnonzero(np.linalg.norm(box - box[0], axis=1) > 0.1)[0]
    suction = _suction(steps)
    assert suction[moved] == 1.0 and suction[-1] == 0.0


def test_push_alone_stalls_where_the_hybrid_goes_from_corner_to_corner(corner_to_corner, tmp_path):
    # Table II: the walls keep the robot from getting behind the box, so push alone can only
    # press it against the north wall and slide it along. That gets there in 7 of 20 planner
    # seeds (`m3p2i bench`, 2026-11-30; seed 0 among them, in 10.95 s), and stalls in the other
    # 13. Seed 3 is one of those: within the hybrid's time and 5 s more, push gets nowhere near
    # the goal.
    hybrid_time = corner_to_corner[0]["time"]
    summary, _, _ = _run("push_corner2", tmp_path, max_time=hybrid_time + 5.0, seed=3)
    assert summary["status"] == "timeout"
    assert summary["measures"]["distance box-goal"] > 3.0


def test_active_inference_moves_to_the_box_then_pushes_or_pulls(tmp_path):
    summary, _, actions = _run("push_pull_aip", tmp_path)
    assert summary["status"] == "success"
    # the action reported is the first of the alternatives {push, pull}; the world's success test
    # may end the episode before the next AIP tick reports idle
    assert actions[0] == "move_to" and set(actions[1:]) <= {"push", "pull", "idle"}
    assert len(actions) > 1
