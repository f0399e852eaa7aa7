"""Behaviour of the active-inference task planner and of the action-template schema.

Cases follow the reference planner's known-good scenarios (battery, pick-place, Panda, push-pull)
and each of its known faults; templates are YAML, parsed exactly as a scenario file would be.
"""

from __future__ import annotations

import itertools
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner_client.aip import ActiveInferencePlanner, FactorAgent, FactorModel, maths
from shared.config import ConfigError, Section
from shared.task_template import parse_task

REPO = Path(__file__).resolve().parents[2]

BATTERY = """
task:
  factors:
    isAt:
      states: [at_goal, not_at_goal]
      actions:
        move_to: {effect: {set: at_goal}, preconditions: [battery_ok]}
    battery:
      states: [battery_ok, battery_not_enough]
      actions:
        go_recharge: {effect: {set: battery_ok}, preconditions: [battery_not_enough]}
  goals: {isAt: at_goal}
"""

PICK_PLACE = """
task:
  defaults: {kappa_d: 0.8}
  factors:
    isCubeAt:
      states: [cube_at_table, cube_at_hand, cube_at_goal]
      actions:
        pick: {effect: {set: cube_at_hand}, preconditions: [cube_at_table]}
        place: {effect: {set: cube_at_goal}, preconditions: [cube_at_hand]}
  goals: {isCubeAt: cube_at_goal}
"""

PANDA = """
task:
  factors:
    AtPlaceLoc:
      states: [at_place_loc, not_at_place_loc]
      actions:
        move_to_place_loc: {effect: {set: at_place_loc}, preconditions: [holding]}
    Holding:
      states: [holding, not_holding]
      actions:
        pick: {effect: {set: holding}, preconditions: [reachable]}
    Reachable:
      states: [reachable, not_reachable]
      actions:
        move_to_reach: {effect: {set: reachable}}
    PlacedOn:
      states: [placed_on, not_placed_on]
      actions:
        place: {effect: {set: placed_on}, preconditions: [at_place_loc, holding]}
  goals: {PlacedOn: placed_on}
"""

PUSH_PULL = """
task:
  factors:
    BlockAt:
      states: [block_at_loc, block_not_at_loc]
      actions:
        push_to_goal: {effect: {set: block_at_loc}, preconditions: [loc_free, close_to]}
        pull_to_goal: {effect: {set: block_at_loc}, preconditions: [loc_free, close_to]}
    LocFree:
      states: [loc_free, loc_not_free]
      actions:
        push_to_non_goal: {effect: {set: loc_free}, preconditions: [close_to]}
        pull_to_non_goal: {effect: {set: loc_free}, preconditions: [close_to]}
    CloseTo:
      states: [close_to, not_close_to]
      actions:
        approach_obj: {effect: {set: close_to}}
  goals: {BlockAt: block_at_loc}
"""

# Battery without go_recharge: move_to's precondition can never be met.
NO_RECHARGE = """
task:
  factors:
    isAt:
      states: [at_goal, not_at_goal]
      actions:
        move_to: {effect: {set: at_goal}, preconditions: [battery_ok]}
    battery:
      states: [battery_ok, battery_not_enough]
  goals: {isAt: at_goal}
"""

TWO_GOALS = """
task:
  factors:
    isAt:
      states: [at_goal, not_at_goal]
      actions:
        move_to: {effect: {set: at_goal}}
    door:
      states: [open, closed]
      actions:
        open_door: {effect: {map: {closed: open}}}
  goals: {isAt: at_goal, door: open}
"""

TEMPLATES = {
    "battery": BATTERY,
    "pick_place": PICK_PLACE,
    "panda": PANDA,
    "push_pull": PUSH_PULL,
    "no_recharge": NO_RECHARGE,
    "two_goals": TWO_GOALS,
}


def template(text: str, source: str = "battery.yaml"):
    return parse_task(Section(yaml.safe_load(text)["task"], source, "task"))


def planner(text: str, **kwargs) -> ActiveInferencePlanner:
    return ActiveInferencePlanner(template(text), **kwargs)


def decide(text: str, obs: tuple[int, ...]):
    p = planner(text)
    return p.step(dict(zip((f.name for f in p.template.factors), obs)))


# --- the reference's known-good scenarios --------------------------------------------------------


@pytest.mark.parametrize("obs, action", [((1, 0), "move_to"), ((1, 1), "go_recharge")])
def test_battery_acts(obs, action):
    d = decide(BATTERY, obs)
    assert (d.status, d.action) == ("running", action)


@pytest.mark.parametrize("battery", [0, 1])
def test_battery_success_at_goal(battery):
    d = decide(BATTERY, (0, battery))
    assert (d.status, d.action, d.alternatives) == ("success", None, ())


@pytest.mark.parametrize(
    "obs, status, action",
    [
        ("cube_at_table", "running", "pick"),
        ("cube_at_hand", "running", "place"),
        ("cube_at_goal", "success", None),
    ],
)
def test_pick_place(obs, status, action):
    d = planner(PICK_PLACE).step({"isCubeAt": obs})
    assert (d.status, d.action) == (status, action)


def panda_expected(at_place: int, holding: int, reachable: int, placed: int) -> str | None:
    if placed == 0:
        return None
    if holding == 1:
        return "move_to_reach" if reachable == 1 else "pick"
    return "move_to_place_loc" if at_place == 1 else "place"


@pytest.mark.parametrize("obs", list(itertools.product([0, 1], repeat=4)))
def test_panda_four_factors(obs):
    d = decide(PANDA, obs)
    expected = panda_expected(*obs)
    assert d.action == expected
    assert d.status == ("success" if expected is None else "running")


@pytest.mark.parametrize(
    "obs, action, alternatives",
    [
        ((1, 0, 0), "push_to_goal", ("push_to_goal", "pull_to_goal")),
        ((1, 1, 0), "push_to_non_goal", ("push_to_non_goal", "pull_to_non_goal")),
        ((1, 0, 1), "approach_obj", ("approach_obj",)),
        ((1, 1, 1), "approach_obj", ("approach_obj",)),
    ],
)
def test_push_pull_alternatives(obs, action, alternatives):
    d = decide(PUSH_PULL, obs)
    assert (d.status, d.action, d.alternatives) == ("running", action, alternatives)


@pytest.mark.parametrize("obs", list(itertools.product([0], [0, 1], [0, 1])))
def test_push_pull_success_has_no_plans(obs):
    d = decide(PUSH_PULL, obs)
    assert (d.status, d.action, d.alternatives) == ("success", None, ())


@pytest.mark.parametrize(
    "obs, action",
    [((1, 0, 0), "push_to_goal"), ((1, 1, 0), "push_to_non_goal"), ((1, 1, 1), "approach_obj")],
)
def test_push_pull_adaptive_returns_first_admissible_only(obs, action):
    p = planner(PUSH_PULL, alternatives=False)
    d = p.step(dict(zip(["BlockAt", "LocFree", "CloseTo"], obs)))
    assert (d.status, d.action, d.alternatives) == ("running", action, (action,))


def test_habit_orders_tied_alternatives():
    text = PUSH_PULL.replace("pull_to_goal: {effect", "pull_to_goal: {habit: 1.005, effect")
    d = decide(text, (1, 0, 0))
    assert d.alternatives == ("pull_to_goal", "push_to_goal")


def test_running_reason_names_the_chain():
    d = decide(PANDA, (1, 1, 1, 1))
    assert d.reason == (
        "move_to_reach -> Reachable.reachable for pick -> Holding.holding for "
        "move_to_place_loc -> AtPlaceLoc.at_place_loc for place -> "
        "goal PlacedOn.placed_on"
    )


# --- the worked numeric check (factor isAt, observing not_at_goal, goal at_goal) -----------------


def test_worked_free_energies():
    factor = template(BATTERY).factor("isAt")
    agent = FactorAgent(FactorModel.from_template(factor, idle_habit=1.01))
    seen = agent.perceive(obs=1)
    policies = agent.evaluate(seen, maths.log_eps(np.array([1.0, 0.0])), agent.model.log_E)
    np.testing.assert_allclose(seen.F, [0.693, 36.84], atol=5e-3)
    np.testing.assert_allclose(policies.G, [36.84, 0.0], atol=5e-3)
    np.testing.assert_allclose(agent.model.log_E - seen.F - policies.G, [-38.22, -37.54], atol=5e-3)
    assert np.argmax(policies.q) == 1  # move_to, by about ln 2


# --- the reference's faults, each fixed ----------------------------------------------------------


@pytest.mark.timeout(10)
def test_unreachable_precondition_is_failure_with_reason():
    d = decide(NO_RECHARGE, (1, 1))
    assert (d.status, d.action, d.alternatives) == ("failure", None, ())
    assert d.reason == (
        "no admissible action towards isAt.at_goal; blocked: move_to needs "
        "battery.battery_ok; no action takes battery from battery_not_enough "
        "to battery_ok"
    )


def test_goal_without_any_achieving_action_is_failure():
    text = BATTERY.replace("{set: at_goal}", "{set: not_at_goal}")
    d = decide(text, (1, 0))
    assert d.status == "failure"
    assert "no action takes isAt from not_at_goal to at_goal" in d.reason


@pytest.mark.parametrize("ticks", [1, 200])
def test_flipped_observation_acted_on_same_tick(ticks):
    p = planner(BATTERY)
    for _ in range(ticks):
        assert p.step({"isAt": 1, "battery": 0}).action == "move_to"
    assert p.step({"isAt": 1, "battery": 1}).action == "go_recharge"
    assert p.step({"isAt": 1, "battery": 0}).action == "move_to"
    assert p.step({"isAt": 0, "battery": 0}).status == "success"


def test_decisions_depend_only_on_the_current_observation():
    p = planner(PANDA)
    rng = np.random.default_rng(0)
    for _ in range(60):
        obs = tuple(int(v) for v in rng.integers(0, 2, size=4))
        d = p.step(dict(zip(["AtPlaceLoc", "Holding", "Reachable", "PlacedOn"], obs)))
        fresh = decide(PANDA, obs)
        assert (d.status, d.action, d.alternatives) == (
            fresh.status,
            fresh.action,
            fresh.alternatives,
        )


def test_success_only_when_all_goals_hold():
    assert decide(TWO_GOALS, (0, 1)).action == "open_door"
    assert decide(TWO_GOALS, (1, 0)).action == "move_to"
    assert decide(TWO_GOALS, (0, 0)).status == "success"


def test_alternatives_list_actions_for_every_unmet_goal():
    d = decide(TWO_GOALS, (1, 1))
    assert (d.action, d.alternatives) == ("move_to", ("move_to", "open_door"))


def test_precondition_that_would_undo_a_held_goal_is_failure_not_oscillation():
    text = """
task:
  factors:
    X:
      states: [x_good, x_bad]
      actions:
        fix_x: {effect: {set: x_good}}
        break_x: {effect: {set: x_bad}}
    Y:
      states: [y_good, y_bad]
      actions:
        fix_y: {effect: {set: y_good}, preconditions: [x_bad]}
  goals: {X: x_good, Y: y_good}
"""
    d = decide(text, (0, 1))
    assert (d.status, d.reason) == (
        "failure",
        "no admissible action towards Y.y_good; blocked: fix_y needs X.x_bad",
    )


def test_alternatives_follow_template_order():
    reordered = (
        PUSH_PULL.replace("push_to_goal:", "TMP:")
        .replace("pull_to_goal:", "push_to_goal:")
        .replace("TMP:", "pull_to_goal:")
    )
    assert decide(reordered, (1, 0, 0)).alternatives == ("pull_to_goal", "push_to_goal")


def test_alternatives_independent_of_hash_seed():
    script = (
        "import yaml; from shared.config import Section; from shared.task_template import "
        "parse_task; from planner_client.aip import ActiveInferencePlanner; "
        f"t = parse_task(Section(yaml.safe_load({PUSH_PULL!r})['task'], 'x', 'task')); "
        "p = ActiveInferencePlanner(t); "
        "print([p.step(dict(BlockAt=1, LocFree=l, CloseTo=0)).alternatives for l in (0, 1)])"
    )
    outputs = {
        subprocess.run(
            [sys.executable, "-c", script],
            capture_output=True,
            text=True,
            check=True,
            cwd=REPO,
            env={**os.environ, "PYTHONHASHSEED": seed},
        ).stdout
        for seed in ("1", "2", "3")
    }
    assert outputs == {
        "[('push_to_goal', 'pull_to_goal'), ('push_to_non_goal', 'pull_to_non_goal')]\n"
    }


@pytest.mark.parametrize("name", TEMPLATES)
def test_idle_is_never_running(name):
    p = planner(TEMPLATES[name])
    actions = {a.name for a in p.template.actions()}
    for obs in itertools.product(*(range(len(f.states)) for f in p.template.factors)):
        d = p.step(dict(zip((f.name for f in p.template.factors), obs)))
        assert "idle" not in d.alternatives
        assert set(d.alternatives) <= actions
        assert (d.status == "running") == (d.action is not None)
        assert d.action is None or d.action == d.alternatives[0]


def test_belief_learned_once_per_tick_however_long_the_search():
    # (1, 1, 1, 1) takes several back-chaining passes; D must still move by exactly κ_d s̄_0.
    p = planner(PANDA)
    d = p.step({"AtPlaceLoc": 1, "Holding": 1, "Reachable": 1, "PlacedOn": 1})
    for beliefs in d.beliefs.values():
        np.testing.assert_allclose(list(beliefs.values()), [0.25, 0.75], atol=1e-12)
    d = planner(PICK_PLACE).step({"isCubeAt": "cube_at_table"})
    expected = (np.full(3, 1 / 3) + 0.8 * np.array([1.0, 0.0, 0.0])) / 1.8
    np.testing.assert_allclose(list(d.beliefs["isCubeAt"].values()), expected, atol=1e-12)


def test_beliefs_stay_finite_and_floored_over_a_long_episode():
    p = planner(BATTERY)
    for _ in range(500):
        d = p.step({"isAt": 1, "battery": 0})
    for beliefs in d.beliefs.values():
        values = np.array(list(beliefs.values()))
        assert np.all(np.isfinite(values)) and np.all(values > 0)
        assert values.sum() == pytest.approx(1.0)
    assert d.beliefs["isAt"]["not_at_goal"] > 0.999


def test_reset_forgets_beliefs():
    p = planner(BATTERY)
    for _ in range(5):
        p.step({"isAt": 1, "battery": 1})
    p.reset()
    assert p.beliefs() == {
        "isAt": {"at_goal": 0.5, "not_at_goal": 0.5},
        "battery": {"battery_ok": 0.5, "battery_not_enough": 0.5},
    }


def test_ambiguity_is_a_non_negative_penalty():
    A = np.array([[0.5, 1.0], [0.5, 0.0]])  # state 0 is ambiguous, state 1 is not
    np.testing.assert_allclose(maths.ambiguity(A), [np.log(2), 0.0], atol=1e-12)
    predicted = np.eye(2)  # policy 0 leads to state 0, policy 1 to state 1
    C = np.zeros(2)
    G = maths.expected_free_energy(A, predicted, C)
    outcomes = A @ predicted
    risk = np.sum(outcomes * (maths.log_eps(outcomes) - C[:, None]), axis=0)
    np.testing.assert_allclose(G - risk, [np.log(2), 0.0], atol=1e-12)


def test_state_posterior_uses_likelihood_of_the_observation():
    # Non-square A (3 outcomes, 2 states): s_0 must be Bayes' rule with Aᵀ o, not A o.
    A = np.array([[0.7, 0.1], [0.2, 0.3], [0.1, 0.6]])
    B = np.eye(2)[:, :, None]
    D = np.array([0.4, 0.6])
    post = maths.state_posterior(A, B, D, obs=1)
    bayes = D * A[1] / np.sum(D * A[1])
    np.testing.assert_allclose(post.s0[:, 0], bayes, atol=1e-9)


# --- numerical safety ----------------------------------------------------------------------------


def test_softmax_does_not_mutate_and_is_stable():
    x = np.array([1000.0, 1001.0, -np.inf])
    before = x.copy()
    y = maths.softmax(x)
    np.testing.assert_array_equal(x, before)
    np.testing.assert_allclose(y, [1 / (1 + np.e), np.e / (1 + np.e), 0.0])
    np.testing.assert_allclose(maths.softmax(np.array([0, 1, 2])), maths.softmax([0.0, 1.0, 2.0]))
    assert maths.softmax(np.array([3, 3])).tolist() == [0.5, 0.5]


def test_normalise_columns_handles_integers_and_zero_columns():
    x = np.array([[1, 3, 0], [1, 1, 0]])
    np.testing.assert_allclose(maths.normalise_columns(x), [[0.5, 0.75, 0.5], [0.5, 0.25, 0.5]])
    assert x.dtype.kind == "i" and x[0, 1] == 3


def test_posteriors_are_distributions_despite_zero_probabilities():
    A = np.eye(3)
    B = np.stack(
        [
            np.eye(3),
            np.array([[0, 0, 0], [1, 1, 1], [0, 0, 0]]),
            np.array([[1, 0, 0], [0, 0, 0], [0, 1, 1]]),
        ],
        axis=2,
    ).astype(float)
    D = np.array([0.0, 0.0, 1.0])  # the prior rules out the observed state
    post = maths.state_posterior(A, B, D, obs=0)
    F = maths.free_energy(D, post)
    G = maths.expected_free_energy(A, post.predicted, maths.log_eps(np.array([0.0, 1.0, 0.0])))
    q = maths.policy_posterior(F, G, np.array([0.0, -np.inf, 0.0]))
    for dist in (post.s0, post.s1, q, maths.model_average(post.s0, q)):
        assert np.all(np.isfinite(dist))
        np.testing.assert_allclose(np.sum(dist, axis=0), 1.0)
    assert np.all(np.isfinite(F)) and np.all(np.isfinite(G)) and q[1] == 0.0


# --- observations --------------------------------------------------------------------------------


def test_observation_by_name_or_index():
    p = planner(BATTERY)
    assert p.step({"isAt": "not_at_goal", "battery": np.int64(1)}).action == "go_recharge"


@pytest.mark.parametrize(
    "obs, message",
    [
        ({"isAt": 1}, "no observation for factor 'battery'"),
        ({"isAt": 1, "battery": 0, "door": 0}, "observation for unknown factor 'door'"),
        (
            {"isAt": 2, "battery": 0},
            "bad observation for factor 'isAt': 2 (expected a state index 0..1",
        ),
        ({"isAt": True, "battery": 0}, "bad observation for factor 'isAt': True"),
        ({"isAt": "nowhere", "battery": 0}, "one of: at_goal, not_at_goal"),
    ],
)
def test_bad_observations_are_rejected(obs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        planner(BATTERY).step(obs)


# --- template schema -----------------------------------------------------------------------------


def test_battery_template_is_parsed_in_yaml_order():
    t = template(BATTERY)
    assert [f.name for f in t.factors] == ["isAt", "battery"]
    move_to = t.factor("isAt").actions[0]
    assert move_to.effect.target("not_at_goal") == "at_goal"
    assert [str(p) for p in move_to.preconditions] == ["battery.battery_ok"]
    assert (t.idle_habit, move_to.habit, t.factor("battery").kappa_d) == (1.01, 1.0, 1.0)
    assert [str(g) for g in t.goals] == ["isAt.at_goal"]


def test_transition_matrices_from_effects():
    model = FactorModel.from_template(template(TWO_GOALS).factor("door"), idle_habit=1.01)
    np.testing.assert_array_equal(model.B[:, :, 0], np.eye(2))
    np.testing.assert_array_equal(model.B[:, :, 1], [[1, 1], [0, 0]])  # closed -> open
    assert model.actions == ("idle", "open_door")
    assert model.log_E[0] > model.log_E[1]
    assert not model.B.flags.writeable


def test_docs_battery_example_parses():
    text = (REPO / "docs" / "action_templates.md").read_text(encoding="utf-8")
    block = re.search(r"```yaml\n(.*?)```", text, re.S).group(1)
    t = template(block, "docs/action_templates.md")
    assert [a.name for a in t.actions()] == ["move_to", "go_recharge"]


P = "battery.yaml: task.factors.isAt"
BAD_TEMPLATES = [
    (
        ("battery_ok]", "battery_okk]"),
        f"{P}.actions.move_to.preconditions[0]: unknown state (got 'battery_okk'; expected one of: "
        "at_goal, battery_not_enough, battery_ok, not_at_goal)",
    ),
    (
        ("[battery_ok]}", "[battery.at_goal]}"),
        f"{P}.actions.move_to.preconditions[0]: unknown state of factor 'battery' "
        "(got 'battery.at_goal'; expected one of: battery_ok, battery_not_enough)",
    ),
    (
        ("[battery_ok]}", "[batt.battery_ok]}"),
        f"{P}.actions.move_to.preconditions[0]: unknown factor (got 'batt.battery_ok'",
    ),
    (
        ("[at_goal, not_at_goal]", "[at_goal, battery_ok]"),
        f"{P}.actions.move_to.preconditions[0]: ambiguous state name (got 'battery_ok'; "
        "expected one of: isAt.battery_ok, battery.battery_ok)",
    ),
    (
        ("[battery_ok]}", "[battery_ok, battery_not_enough]}"),
        f"{P}.actions.move_to.preconditions[1]: contradicts precondition battery.battery_ok",
    ),
    (
        ("[battery_ok]}", "[battery_ok, battery_ok]}"),
        f"{P}.actions.move_to.preconditions[1]: duplicate precondition (got 'battery_ok'",
    ),
    (
        ("{set: at_goal}, preconditions: [battery_ok]", "{set: at_gaol}"),
        f"{P}.actions.move_to.effect.set: unknown state of factor 'isAt' (got 'at_gaol'; "
        "expected a state of factor 'isAt': at_goal, not_at_goal)",
    ),
    (
        ("{effect: {set: at_goal}, ", "{"),
        f"{P}.actions.move_to.effect: missing required key (expected {{set: state}}",
    ),
    (
        ("{set: at_goal}, preconditions", "identity, preconditions"),
        f"{P}.actions.move_to.effect: an identity effect never changes the state",
    ),
    (
        ("{set: at_goal}, preconditions", "{map: {at_goal: at_goal}}, preconditions"),
        f"{P}.actions.move_to.effect: a map that moves no state never changes anything",
    ),
    (
        ("{set: at_goal}, preconditions", "{map: {there: at_goal}}, preconditions"),
        f"{P}.actions.move_to.effect.map.there: unknown state of factor 'isAt' (got 'there'",
    ),
    (
        ("{set: at_goal}, preconditions", "{set: at_goal, map: {}}, preconditions"),
        f"{P}.actions.move_to.effect: must have exactly one of 'set' or 'map'",
    ),
    (
        ("go_recharge:", "move_to:"),
        "battery.yaml: task.factors.battery.actions.move_to: duplicate action, already in factor "
        "'isAt' (got 'move_to'; expected unique action names)",
    ),
    (("move_to:", "idle:"), f"{P}.actions.idle: 'idle' is implicit in every factor"),
    (
        ("preconditions: [battery_ok]", "precondition: [battery_ok]"),
        f"{P}.actions.move_to.precondition: unknown key (expected one of: effect, habit, "
        "preconditions)",
    ),
    (("[at_goal, not_at_goal]", "[]"), f"{P}.states: needs at least two states (got []"),
    (("[at_goal, not_at_goal]", "[at_goal, at_goal]"), f"{P}.states: duplicate state 'at_goal'"),
    (("[at_goal, not_at_goal]", "[at_goal, on]"), f"{P}.states[1]: bad state name (got True"),
    (
        ("goals: {isAt: at_goal}", "goals: {isAtt: at_goal}"),
        "battery.yaml: task.goals.isAtt: unknown factor (got 'isAtt'; expected one of: isAt, "
        "battery)",
    ),
    (
        ("goals: {isAt: at_goal}", "goals: {isAt: there}"),
        "battery.yaml: task.goals.isAt: unknown state of factor 'isAt' (got 'there'",
    ),
    (("goals: {isAt: at_goal}", "goals: {}"), "battery.yaml: task.goals: needs at least one goal"),
    (("  goals: {isAt: at_goal}\n", ""), "battery.yaml: task.goals: missing required section"),
    (
        ("  factors:", "  defaults: {habit: 1.2}\n  factors:"),
        "battery.yaml: task.defaults.habit: must be below idle_habit (1.01) (got 1.2",
    ),
    (
        ("  factors:", "  defaults: {kappa: 1.0}\n  factors:"),
        "battery.yaml: task.defaults.kappa: unknown key",
    ),
    (
        ("  factors:", "  defaults: {kappa_d: -1}\n  factors:"),
        "battery.yaml: task.defaults.kappa_d: must be >= 0 (got -1",
    ),
]


@pytest.mark.parametrize(
    "edit, message",
    BAD_TEMPLATES,
    ids=[m.split(": ", 2)[1] + " " + str(i) for i, (_, m) in enumerate(BAD_TEMPLATES)],
)
def test_template_errors(edit, message):
    old, new = edit
    assert old in BATTERY
    with pytest.raises(ConfigError) as err:
        template(BATTERY.replace(old, new, 1))
    assert str(err.value).startswith(message)


def test_empty_factors_is_an_error():
    with pytest.raises(
        ConfigError, match=re.escape("battery.yaml: task.factors: needs at least one factor")
    ):
        parse_task(Section({"factors": {}, "goals": {"a": "b"}}, "battery.yaml", "task"))
