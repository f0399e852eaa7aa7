"""Scenario loading: the shipped scenarios load, and bad files fail naming file, key and value."""

import copy

import pytest
import yaml

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
    assert "world.timestep" in msg and "'fast'" in msg and "seconds > 0" in msg


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
