"""Panda pick-and-place (paper III.A.2, III.C): the action template's decisions, and both processes
end to end in lock-step: the reactive run (stacking with the cube moved, stolen from the hand, goal
blocked, unstacked) and the multi-modal grasp past a moving obstacle, in both of its cases (side
grasp in the shelf, top grasp on the table). Plain stacking (pick_place.yaml) runs end to end in
tests/e2e/test_realtime.py, in real time. Each run prints its position and orientation error (Table
III's columns); ``-s`` shows them."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from planner_client.aip import ActiveInferencePlanner
from shared.scenario import load_scenario
from shared.scene import compile_model
from tests.episodes import Episode

START = {
    "preplace": "not_at_preplace",
    "holding": "not_holding",
    "reachable": "not_reachable",
    "placed": "not_placed_on",
    "goal": "goal_free",
}


def _decide(scenario: str, **observed):
    sc = load_scenario(scenario)
    obs = {k: v for k, v in {**START, **observed}.items() if k in sc.observers}
    return ActiveInferencePlanner(sc.task).step(obs)


@pytest.mark.parametrize(
    "observed, action",
    [
        ({}, "reach"),
        ({"reachable": "reachable"}, "pick"),
        ({"reachable": "reachable", "holding": "holding"}, "move2place"),
        ({"holding": "holding", "preplace": "at_preplace"}, "place"),
        ({"goal": "goal_blocked"}, "reach"),  # picking does not need the goal
    ],
)
def test_template_chains_reach_pick_move2place_place(observed, action):
    d = _decide("pick_place_reactive", **observed)
    assert (d.status, d.action) == ("running", action)


def test_a_blocked_goal_stops_the_robot_with_the_reason():
    d = _decide(
        "pick_place_reactive", reachable="reachable", holding="holding", goal="goal_blocked"
    )
    assert d.status == "failure"
    assert "no action takes goal from goal_blocked to goal_free" in d.reason


def test_placed_is_success_and_the_shelf_template_offers_both_grasps():
    assert _decide("pick_place_reactive", placed="placed_on").status == "success"
    d = _decide("pick_shelf")
    assert d.alternatives == ("reach_top", "reach_side")
    assert load_scenario("pick_shelf").action_objectives["reach_side"] == "reach_side"


# ------------------------------------------------------------------ end to end (slow)
#
# Two seeds of each Panda scenario, run in parallel (tests/episodes.py). Success is asserted as a
# rate, at least one of the two: over 50 seeds each scenario succeeds in at least 98 % (README,
# Results), so both seeds failing on another machine has a probability under 0.1 %. Every
# episode, successful or not, must show what does not depend on the chaotic details: the order
# of active inference's decisions, the re-grasp after a disturbance, the grasp the mode chose.

SEEDS = (0, 1)


def episode_specs(out):
    """This module's episodes, for the session's one pool (tests/conftest.py); the longest
    (the reactive run's four disturbances) first, so that they do not finish the pool alone."""
    return [(name, name, seed) for name in ("pick_place_reactive", "pick_shelf") for seed in SEEDS]


@pytest.fixture(scope="module")
def panda(lockstep_episodes):
    return lockstep_episodes


def _report(name: str, ep: Episode) -> None:
    m = ep.summary.get("measures", {})
    print(
        f"\n{name} seed {ep.row['seed']}: {ep.row['status']} at t={float(ep.row['time']):.2f} s, "
        f"position error {m.get('position error cube_a-cube_b', float('nan')):.4f} m, "
        f"orientation error {m.get('orientation error cube_a-cube_b', float('nan')):.4f}, "
        f"planner {float(ep.row['planner_hz']):.1f} Hz, wall {float(ep.row['trial_wall']):.0f} s"
    )


def _succeeded_within_tolerance(name: str, episodes: dict) -> list[Episode]:
    """The successful episodes of ``name`` (at least one), each stacked within Eq. 26's 1 cm and
    φ 0.01."""
    eps = [episodes[(name, s)] for s in SEEDS]
    for ep in eps:
        _report(name, ep)
    won = [ep for ep in eps if ep.success]
    assert won, f"{name}: no seed of {SEEDS} succeeded"
    for ep in won:
        m = ep.summary["measures"]
        assert (
            m["position error cube_a-cube_b"] < 0.01 and m["orientation error cube_a-cube_b"] < 0.01
        )
    return won


def _first_occurrences(actions: list[str]) -> list[str]:
    return [a for i, a in enumerate(actions) if a not in actions[:i]]


@pytest.mark.slow
def test_reactive_run_picks_the_stolen_cube_again_and_succeeds(panda):
    for ep in _succeeded_within_tolerance("pick_place_reactive", panda):
        # the template's chain up to the theft (the goal's block then reports a failure)
        assert _first_occurrences(ep.actions)[:3] == ["reach", "pick", "move2place"]
        assert [e["object"] for e in ep.disturbances] == [
            "cube_a",
            "cube_a",
            "blocker",
            "blocker",
            "cube_a",
        ]
        assert ep.actions.count("place") >= 2  # placed, unstacked, placed again
    for seed in SEEDS:
        ep = panda[("pick_place_reactive", seed)]
        # stolen during transport: active inference goes back to reach and pick, whatever the
        # hand does next; with the goal blocked it reports failure instead of placing
        after_steal = ep.actions[ep.actions.index("move2place") + 1 :]
        assert after_steal[:2] == ["reach", "pick"], ep.actions
        assert "failure" in ep.actions[ep.actions.index("move2place") :]
        assert ep.actions.count("pick") >= 2  # the re-grasp happened


def _grasp_axis(scenario: str, records) -> np.ndarray:
    """World z axis of the hand (tool centre point frame) when the first ``pick`` starts,
    replayed from the logged state ``[3]``: (0, 0, -1) for a top grasp, level for a side grasp."""
    sc = load_scenario(scenario)
    model = compile_model(sc)
    data = mujoco.MjData(model)
    step = next(r for r in records if r.get("kind") == "step" and r["action"] == "pick")
    data.qpos[:] = step["qpos"]
    mujoco.mj_kinematics(model, data)
    return data.site("grasp").xmat.reshape(3, 3)[:, 2].copy()


@pytest.mark.slow
def test_shelf_scenario_grasps_from_the_side_in_the_shelf_and_from_above_on_the_table(panda):
    """Seed 0 draws the cube in the shelf, seed 1 on the table (``world.randomize choose``, from
    numpy's PCG64, the same on every machine). The grasp is M3P2I's choice between two modes
    with very different costs, not a chaotic detail: over 20 seeds every shelf cube was
    side-grasped and every table cube top-grasped, with no contact with the moving obstacle."""
    _succeeded_within_tolerance("pick_shelf", panda)
    for seed, case in zip(SEEDS, ("shelf", "table")):
        ep = panda[("pick_shelf", seed)]
        start_z = ep.records[0]["initial"][0]["pos"][2]
        assert (start_z > 1.2) == (case == "shelf")  # shelf at 1.3 m, table 1.025
        z_hand = _grasp_axis("pick_shelf", ep.records)
        print(
            f"pick_shelf seed {seed} ({case}): hand z axis at pick "
            f"{np.round(z_hand, 2).tolist()}, collisions {ep.row['collisions']}"
        )
        if case == "table":
            assert z_hand[2] < -0.9  # pointing down
        else:
            assert abs(z_hand[2]) < 0.2  # level
        assert float(ep.row["collisions"]) == 0
        assert "modes ['reach_top', 'reach_side']" in ep.planner_log  # M3P2I sampled both
