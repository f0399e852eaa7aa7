"""planner.confirm: an observer flickering at its threshold (noisy poses, a noisy battery) no
longer switches the action every tick; a real change is still acted on, within the confirm
time plus one active-inference period. Deterministic (a seeded noise stream, no physics)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import yaml

from planner_client.build import build_motion_planner, build_task
from planner_client.task import ConfirmedObservation
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, parse_scenario
from shared.scene import initial_data

PERIOD = 0.2  # battery_recharge's aip_period


def _task(confirm):
    raw = yaml.safe_load((SCENARIO_DIR / "battery_recharge.yaml").read_text())
    if confirm is not None:
        raw["planner"]["confirm"] = confirm
    sc = parse_scenario(raw, str(SCENARIO_DIR / "battery_recharge.yaml"))
    planner = build_motion_planner(sc, threads=2)
    return build_task(sc, planner), initial_data(sc, planner.problem.model)


def _threshold(task, data) -> float:
    """The battery level (%) at which battery_enough flips, from the robot's start pose."""
    lo, hi = 0.0, 100.0
    for _ in range(50):
        mid = (lo + hi) / 2
        ok = task.observer(data, {"battery": mid})["battery"] == "battery_ok"
        lo, hi = (lo, mid) if ok else (mid, hi)
    return hi


def _switches(confirm, seconds=10.0) -> tuple[int, list[str]]:
    """Action changes over ``seconds`` of ticks with the battery at its threshold ± 0.5 %."""
    task, data = _task(confirm)
    level = _threshold(task, data)
    noise = np.random.default_rng(7).normal(0.0, 0.5, int(seconds / PERIOD) + 1)
    actions = [
        task.decide(data, {"battery": level + n}, i * PERIOD).action for i, n in enumerate(noise)
    ]
    return sum(a != b for a, b in itertools.pairwise(actions)), actions


def test_a_flickering_observer_switches_the_action_every_few_ticks_without_confirm():
    switches, actions = _switches(None)
    assert set(actions) == {"move_to", "go_recharge"} and switches >= 15


def test_with_confirm_the_action_holds_through_the_flicker():
    switches, _ = _switches({"battery": 0.6})
    assert switches <= 3


def test_a_real_change_is_acted_on_within_confirm_and_one_period():
    task, data = _task({"*": 0.6})
    level = _threshold(task, data)
    t = 0.0
    for _ in range(10):  # well charged: heads for the goal
        assert task.decide(data, {"battery": level + 20}, t).action == "move_to"
        t += PERIOD
    changed_at = t
    while task.decide(data, {"battery": level - 20}, t).action != "go_recharge":
        t += PERIOD / 4  # the loop asks every planner iteration
        assert t - changed_at <= 0.6 + PERIOD + 1e-9, "the drained battery was not acted on"
    assert t - changed_at >= 0.6 - 1e-9  # ... and not before it was confirmed


def test_the_filter_holds_a_state_until_the_new_one_persists():
    f = ConfirmedObservation({"a": 0.5})
    assert f({"a": "x", "b": "p"}, 0.0) == {"a": "x", "b": "p"}
    assert f({"a": "y", "b": "q"}, 0.1) == {"a": "x", "b": "q"}  # b unconfirmed: at once
    assert f({"a": "x"}, 0.2)["a"] == "x"  # a break restarts the wait
    assert f({"a": "y"}, 0.3)["a"] == "x"
    assert f({"a": "y"}, 0.79)["a"] == "x"
    assert f({"a": "y"}, 0.8)["a"] == "y"


def test_per_state_times_give_hysteresis():
    """``{reachable: {not_reachable: 0.3}}``: a flickering observer takes 'reachable' at once and
    keeps it; only 0.3 s without a break of 'not_reachable' lets it go."""
    f = ConfirmedObservation({"reach": {"no": 0.3}})
    assert f({"reach": "no"}, 0.0)["reach"] == "no"
    assert f({"reach": "yes"}, 0.1)["reach"] == "yes"  # to 'yes': at once
    for i in range(10):  # flicker: 'yes' holds
        assert f({"reach": "no" if i % 2 == 0 else "yes"}, 0.2 + 0.1 * i)["reach"] == "yes"
    assert f({"reach": "no"}, 1.2)["reach"] == "yes"
    assert f({"reach": "no"}, 1.4)["reach"] == "yes"
    assert f({"reach": "no"}, 1.5)["reach"] == "no"  # 0.3 s without a break


@pytest.mark.parametrize(
    "confirm, message",
    [
        (
            {"battery": {"battery_empty": 0.5}},
            r"planner.confirm.battery.battery_empty: not a state "
            r"of the factor.*one of: battery_ok",
        ),
        ({"batery": 0.5}, "planner.confirm.batery: not a factor of the task"),
        (-1, "planner.confirm"),
        ({"battery": "soon"}, "planner.confirm"),
    ],
)
def test_confirm_is_checked(confirm, message):
    raw = yaml.safe_load((SCENARIO_DIR / "battery_recharge.yaml").read_text())
    raw["planner"]["confirm"] = confirm
    with pytest.raises(ConfigError, match=message):
        parse_scenario(raw, "b.yaml")
    nav = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    nav["planner"]["confirm"] = 0.5
    with pytest.raises(ConfigError, match="only a task's observers are confirmed"):
        parse_scenario(nav, "n.yaml")
