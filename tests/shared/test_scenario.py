"""Scenario loading: the shipped scenarios load, and bad files fail naming file, key and value."""

import copy

import numpy as np
import pytest
import yaml

from server.world import SimWorld
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from shared.scene import build_spec, compile_model


@pytest.fixture
def nav_raw():
    return yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())


@pytest.mark.parametrize("path", sorted(SCENARIO_DIR.glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_scenarios_load_and_compile(path):
    sc = load_scenario(path)
    model = compile_model(sc, build_spec(sc))
    assert model.nu >= 1 and sc.hash


def test_lookup_by_name_and_hash_is_content_based(nav_raw):
    a = load_scenario("navigation")
    b = parse_scenario(copy.deepcopy(nav_raw), "elsewhere.yaml")
    assert a.hash == b.hash
    nav_raw["world"]["objects"][0]["pos"][0] += 0.01
    assert parse_scenario(nav_raw, "x.yaml").hash != a.hash


def _error(raw) -> str:
    with pytest.raises(ConfigError) as info:
        parse_scenario(raw, "test.yaml")
    return str(info.value)


def test_missing_key(nav_raw):
    del nav_raw["episode"]["max_time"]
    assert _error(nav_raw).startswith("test.yaml: episode.max_time: missing required key")


def test_unknown_key_is_an_error_not_a_default(nav_raw):
    nav_raw["planner"]["horizn"] = 12
    msg = _error(nav_raw)
    assert msg.startswith("test.yaml: planner.horizn: unknown key")
    assert "horizon" in msg


def test_wrong_type_names_value_and_expectation(nav_raw):
    nav_raw["world"]["timestep"] = "fast"
    msg = _error(nav_raw)
    assert "world.timestep" in msg and "'fast'" in msg and "seconds in [1e-06, 10]" in msg


def test_bad_robot_name_lists_the_registered_robots(nav_raw):
    nav_raw["robot"]["model"] = "pointbot"
    msg = _error(nav_raw)
    assert "robot.model: unknown robot" in msg and "'pointbot'" in msg and "point_robot" in msg


def test_error_in_a_list_item_names_its_index(nav_raw):
    nav_raw["world"]["objects"][2]["size"] = [0.3]
    msg = _error(nav_raw)
    assert "world.objects[2].size" in msg and "2 half-sizes for a cylinder" in msg


def test_unknown_predicate_in_success(nav_raw):
    nav_raw["episode"]["success"] = [{"close_to": {"a": "robot", "b": "goal"}}]
    assert "episode.success[0].close_to: unknown predicate" in _error(nav_raw)


def test_mode_must_name_an_objective(nav_raw):
    nav_raw["modes"] = ["navigate", "fly"]
    assert "modes[1]: not an objective of this scenario" in _error(nav_raw)


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="no such scenario"):
        load_scenario(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scenario(bad)


def test_robot_qpos_sets_the_start_state_not_the_joint_zero():
    # MuJoCo measures hinge angles from qpos0: the Panda at robot.qpos must be drawn exactly like
    # its own "home" keyframe, and its joint zero must stay where the MJCF puts it
    import mujoco

    from shared.robots import get_robot
    from shared.scene import initial_data

    sc = load_scenario("pick_place")
    model = compile_model(sc)
    data = initial_data(sc, model)
    np.testing.assert_array_equal(model.qpos0[:9], 0.0)
    ref = mujoco.MjModel.from_xml_path(str(get_robot("panda").path))
    ref_data = mujoco.MjData(ref)
    mujoco.mj_resetDataKeyframe(ref, ref_data, ref.key("home").id)
    mujoco.mj_forward(ref, ref_data)
    np.testing.assert_allclose(data.site("grasp").xpos, ref_data.site("grasp").xpos, atol=1e-12)


def test_success_must_hold_for_episode_hold_seconds(nav_raw):
    from server.world import SimWorld

    nav_raw["episode"]["success"] = [{"near": {"a": "robot", "b": "goal", "within": 10.0}}]
    nav_raw["episode"]["hold"] = 0.2
    world = SimWorld(parse_scenario(nav_raw, "x.yaml"))
    steps = 0
    while world.status == "running":
        world.step(np.zeros(2))
        steps += 1
    assert world.status == "success" and steps == 5  # 0.05 s steps: held from t = 0.05
    nav_raw["episode"]["hold"] = -1
    assert "episode.hold: must be >= 0" in _error(nav_raw)


def test_a_safe_stop_keeps_the_gripper_command():
    from server.world import SimWorld

    world = SimWorld(load_scenario("pick_place"))
    np.testing.assert_array_equal(world.safe_command(), 0.0)  # before any command
    ctrl = np.full(8, 0.5)
    ctrl[7] = 0.08
    world.step(ctrl)
    expected = np.zeros(8)
    expected[7] = 0.08  # joints stop, the hand stays open
    np.testing.assert_array_equal(world.safe_command(), expected)


def _shelf_raw():
    return yaml.safe_load((SCENARIO_DIR / "pick_shelf.yaml").read_text())


def test_randomize_choose_draws_one_of_the_listed_start_positions():
    raw = _shelf_raw()
    spots = [[0.1, -0.1, 1.025], [0.1, -0.3, 1.3]]
    raw["world"]["randomize"] = [{"object": "cube_a", "choose": spots}]
    sc = parse_scenario(raw, "test.yaml")
    assert sc.world.randomize[0].choose == tuple(tuple(p) for p in spots)
    drawn = set()
    for seed in range(8):  # the server draws at reset, from its --seed
        world = SimWorld(sc, seed=seed)
        drawn.add(tuple(round(v, 6) for v in world.initial[0]["pos"]))
    assert drawn == {tuple(p) for p in spots}


@pytest.mark.parametrize(
    "entry, message",
    [
        (
            {"choose": [[0.1, 0.0, 1.0]]},
            "world.randomize[0].choose: needs at least two start positions",
        ),
        (
            {"choose": [[0.1, 0.0, 1.0], [0.2, 0.0]]},
            "world.randomize[0].choose[1]: needs 3 numbers",
        ),
        (
            {"choose": [[0.1, 0.0, 1.0], [0.2, 0.0, 1.0]], "x": [0.0, 0.1]},
            "world.randomize[0].x: give either choose or x/y ranges, not both",
        ),
    ],
)
def test_randomize_choose_errors_name_the_key(entry, message):
    raw = _shelf_raw()
    raw["world"]["randomize"] = [{"object": "cube_a", **entry}]
    assert message in _error(raw)


def test_a_move_fires_delay_seconds_after_its_condition_first_holds(nav_raw):
    always = {"near": {"a": "robot", "b": "pillar", "within": 100.0}}
    nav_raw["world"]["disturbances"] = [
        {"move": {"object": "pillar", "when": always, "delay": 0.5, "pos": [0.0, 3.0, 0.2]}},
        # chained: holds once the pillar is near the goal, i.e. after the first move
        {
            "move": {
                "object": "block_a",
                "delay": 0.25,
                "pos": [2.0, -2.0, 0.2],
                "when": {"near": {"a": "pillar", "b": "goal", "within": 3.5}},
            }
        },
    ]
    world = SimWorld(parse_scenario(nav_raw, "x.yaml"))
    for _ in range(30):  # 1.5 s of 0.05 s steps
        world.step(np.zeros(2))
    moved = [(e["object"], round(e["time"], 2)) for e in world.events if "object" in e]
    # the condition holds before the first step (t = 0); the chained one from the step after
    # the pillar moved (kinematics one step old), t = 0.55
    assert moved == [("pillar", 0.5), ("block_a", 0.8)]
    np.testing.assert_allclose(world.data.body("pillar").xpos, [0.0, 3.0, 0.2])


def test_a_delay_needs_a_condition(nav_raw):
    nav_raw["world"]["disturbances"] = [
        {"move": {"object": "pillar", "delay": 1.0, "pos": [0, 3, 0.2]}}
    ]
    assert (
        "world.disturbances[0].move.delay: a delay counts from when the `when` condition "
        "first holds"
    ) in _error(nav_raw)
