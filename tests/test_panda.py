"""Panda pick-and-place (paper III.A.2, III.C): the action template's decisions, and both processes
end to end in lock-step: normal stacking, the reactive run (cube moved, stolen from the hand, goal
blocked, unstacked) and the shelf grasp past a moving obstacle. Each run prints its position and
orientation error (Table III's columns)."""

from __future__ import annotations

import time

import pytest

from planner_client.aip import ActiveInferencePlanner
from server.episode_log import read_log
from shared.scenario import load_scenario
from tests.helpers import free_port_block, start_planner, start_server, stop

START = {"preplace": "not_at_preplace", "holding": "not_holding", "reachable": "not_reachable",
         "placed": "not_placed_on", "goal": "goal_free"}


def _decide(scenario: str, **observed):
    sc = load_scenario(scenario)
    obs = {k: v for k, v in {**START, **observed}.items() if k in sc.observers}
    return ActiveInferencePlanner(sc.task).step(obs)


@pytest.mark.parametrize("observed, action", [
    ({}, "reach"),
    ({"reachable": "reachable"}, "pick"),
    ({"reachable": "reachable", "holding": "holding"}, "move2place"),
    ({"holding": "holding", "preplace": "at_preplace"}, "place"),
    ({"goal": "goal_blocked"}, "reach"),       # picking does not need the goal
])
def test_template_chains_reach_pick_move2place_place(observed, action):
    d = _decide("pick_place_reactive", **observed)
    assert (d.status, d.action) == ("running", action)


def test_a_blocked_goal_stops_the_robot_with_the_reason():
    d = _decide("pick_place_reactive", reachable="reachable", holding="holding", goal="goal_blocked")
    assert d.status == "failure"
    assert "no action takes goal from goal_blocked to goal_free" in d.reason


def test_placed_is_success_and_the_shelf_template_offers_both_grasps():
    assert _decide("pick_place_reactive", placed="placed_on").status == "success"
    d = _decide("pick_shelf")
    assert d.alternatives == ("reach_top", "reach_side")
    assert load_scenario("pick_shelf").plan["reach_side"] == "reach_side"


# ------------------------------------------------------------------ end to end (slow)

def _run(scenario: str, tmp_path, timeout: float = 240):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    started = time.monotonic()
    server = start_server(scenario, port, log)
    planner = start_planner(scenario, port)
    try:
        out, _ = server.communicate(timeout=timeout)
        planner_out, _ = planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    wall = time.monotonic() - started
    assert server.returncode == 0, out + planner_out
    records = read_log(log)
    summary = records[-1]
    m = summary["measures"]
    print(f"\n{scenario}: {summary['status']} at t={summary['time']:.2f} s, position error "
          f"{m['position error cube_a-cube_b']:.4f} m, orientation error "
          f"{m['orientation error cube_a-cube_b']:.4f}, planner {summary['planner_hz']:.1f} Hz, "
          f"wall {wall:.0f} s")
    actions = [r["action"] for r in records if r.get("what") == "action"]
    events = [r for r in records if r.get("what") == "disturbance"]
    return summary, actions, events, planner_out


def _errors_within_tolerance(summary):
    m = summary["measures"]
    assert summary["status"] == "success"
    assert m["position error cube_a-cube_b"] < 0.01 and m["orientation error cube_a-cube_b"] < 0.01


@pytest.mark.slow
def test_pick_place_stacks_the_cubes(tmp_path):
    summary, actions, _, _ = _run("pick_place", tmp_path)
    _errors_within_tolerance(summary)
    firsts = [a for i, a in enumerate(actions) if a not in actions[:i]]
    assert firsts[:4] == ["reach", "pick", "move2place", "place"]


@pytest.mark.slow
def test_reactive_run_picks_the_stolen_cube_again_and_succeeds(tmp_path):
    summary, actions, events, _ = _run("pick_place_reactive", tmp_path)
    _errors_within_tolerance(summary)
    assert [e["object"] for e in events] == ["cube_a", "cube_a", "blocker", "blocker", "cube_a"]
    # stolen during transport: back to reach and pick; unstacked after placement: once more
    assert actions.count("pick") >= 3 and actions.count("place") >= 2
    after_steal = actions[actions.index("move2place") + 1:]
    assert after_steal[:2] == ["reach", "pick"]


@pytest.mark.slow
def test_shelf_grasp_fuses_both_grasp_modes_and_succeeds(tmp_path):
    summary, actions, _, planner_out = _run("pick_shelf", tmp_path)
    _errors_within_tolerance(summary)
    assert "modes ['reach_top', 'reach_side']" in planner_out   # M3P2I sampled both grasps
    assert actions[0] == "reach_top" and "place" in actions
