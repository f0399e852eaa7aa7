"""Push, pull and hybrid push-pull end to end (paper III.B, Tables I-II): both processes in
lock-step over loopback, a few seeds of each case run in parallel (tests/episodes.py).

Success is asserted as a rate with a margin taken from the bench (`m3p2i bench`, 20-60 seeds per
case; docs/results.md), never on one seed: another machine rounds differently and a pushed
box's contacts amplify it. What holds in every episode is asserted in every episode: the pinned
suction of each mode, the moving obstacle never touched, active inference's choice of actions.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.episodes import with_max_time

pytestmark = pytest.mark.slow

SUCTION = 2  # point_robot_suction: ctrl = (vel_x, vel_y, suction)
BOX = slice(2, 4)  # the box's x, y in qpos, after the robot's two slide joints

# The hybrid's corner-to-corner episodes take 9-12 s (mean 10.4 s over 20 seeds); push alone gets
# the hybrid's longest time to show that it mostly stalls.
CORNER2_PUSH_TIME = 12.0
PAIR = (0, 1)
HYBRID_SEEDS = (0, 1)
PUSH_SEEDS = tuple(range(5))


def episode_specs(out):
    """This module's episodes, for the session's one pool (tests/conftest.py)."""
    push_corner2 = with_max_time("push_corner2", CORNER2_PUSH_TIME, out)
    specs = [("push_pull_corner2", "push_pull_corner2", seed) for seed in HYBRID_SEEDS]
    specs += [("push_corner2", push_corner2, seed) for seed in PUSH_SEEDS]
    specs += [
        (name, name, seed)
        for name in (
            "push",
            "pull",
            "push_dynamic_obstacle",
            "pull_dynamic_obstacle",
            "push_pull_corner1",
            "push_pull_aip",
        )
        for seed in PAIR
    ]
    return specs


@pytest.fixture(scope="module")
def episodes(lockstep_episodes):
    return lockstep_episodes


def _runs(episodes, name: str, seeds=PAIR) -> list:
    runs = [episodes[(name, s)] for s in seeds]
    print(
        f"\n{name}: "
        + ", ".join(
            f"seed {r.row['seed']} {r.row['status']} ({float(r.row['time']):.2f} s)" for r in runs
        )
    )
    return runs


def _successes(runs) -> int:
    return sum(r.success for r in runs)


def _suction(run) -> np.ndarray:
    return np.array([s["ctrl"][SUCTION] for s in run.steps])


def test_push_reaches_the_goal_with_the_suction_off(episodes):
    """Push succeeded in every bench trial (60/60 among the moving obstacle); at least 1 of 2."""
    runs = _runs(episodes, "push")
    assert _successes(runs) >= 1
    for r in runs:
        assert not _suction(r).any()
        if r.success:
            assert r.summary["measures"]["distance box-goal"] <= 0.1


def test_pull_drags_the_box_to_the_goal_with_the_suction_on(episodes):
    """Pull: 59/60 among the moving obstacle; at least 1 of 2."""
    runs = _runs(episodes, "pull")
    assert _successes(runs) >= 1
    for r in runs:
        assert (_suction(r) == 1.0).all()


@pytest.mark.parametrize("scenario", ["push_dynamic_obstacle", "pull_dynamic_obstacle"])
def test_push_and_pull_among_a_moving_obstacle_never_touch_it(episodes, scenario):
    """Table I's setting: the world moves the obstacle, the planner only sees its poses. No
    contact in 120 bench trials, so none is allowed in any episode here."""
    runs = _runs(episodes, scenario)
    assert _successes(runs) >= 1
    for r in runs:
        assert float(r.row["collisions"]) == 0
        mover = np.array([s["mocap_pos"][-1][:2] for s in r.steps])
        assert np.ptp(mover[:, 1]) > 1.0  # it did move across the way


def test_hybrid_puts_the_box_into_a_corner(episodes):
    """20/20 in the bench; at least 1 of 2."""
    assert _successes(_runs(episodes, "push_pull_corner1")) >= 1


def test_hybrid_takes_the_box_from_corner_to_corner_pulling_then_pushing(episodes):
    """20/20 in the bench; at least 1 of 2 here. In each success the executed suction follows
    the dominant mode: on when the box leaves its corner (pulled out), off at the end (pushed
    into the other corner)."""
    runs = _runs(episodes, "push_pull_corner2", HYBRID_SEEDS)
    assert _successes(runs) >= 1
    for r in (r for r in runs if r.success):
        box = np.array([s["qpos"][BOX] for s in r.steps])
        moved = np.flatnonzero(np.linalg.norm(box - box[0], axis=1) > 0.1)[0]
        suction = _suction(r)
        assert suction[moved] == 1.0 and suction[-1] == 0.0


def test_push_alone_mostly_stalls_where_the_hybrid_goes_from_corner_to_corner(episodes):
    """Table II: the walls keep the robot from getting behind the box, so push alone can only
    press it against the north wall and slide it along; that reached the goal in 7 of 20 bench
    seeds (35 %). Here push gets the hybrid's longest time (12 s) on 5 seeds and must fail in at
    least 1: with a 35 % success rate all 5 succeed with probability 0.5 % (8 seeds and 2
    failures before 2026-12-01: the same odds, 60 s more of the suite)."""
    runs = _runs(episodes, "push_corner2", PUSH_SEEDS)
    failures = [r for r in runs if not r.success]
    assert failures
    for r in failures:
        assert r.row["status"] == "timeout"


def test_active_inference_moves_to_the_box_then_pushes_or_pulls(episodes):
    for r in _runs(episodes, "push_pull_aip"):
        # the action reported is the first of the alternatives {push, pull}; the world's success
        # test may end the episode before the next AIP tick reports idle
        assert r.actions[0] == "move_to" and set(r.actions[1:]) <= {"push", "pull", "idle"}
        assert len(r.actions) > 1
    assert _successes(_runs(episodes, "push_pull_aip")) >= 1
