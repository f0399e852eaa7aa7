"""``base: NAME``: a scenario written as the changes to another (a robot owner's variant of a
shipped scenario in a few lines): mappings merged key by key, lists and values replaced, ``null``
removes a key; errors name the file and the base."""

from pathlib import Path

import pytest
import yaml

from shared.config import ConfigError
from shared.config_files import ENV_VAR
from shared.scenario import SCENARIO_DIR, load_scenario


@pytest.fixture
def user(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(ENV_VAR, raising=False)
    return tmp_path


def _write(folder: Path, name: str, raw: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_variant_changes_what_it_names_and_inherits_the_rest(user):
    nav = load_scenario("navigation")
    path = _write(
        user,
        "fast_nav",
        {
            "base": "navigation",
            "name": "fast_nav",
            "planner": {"samples": 50},  # one key of a mapping
            "episode": {"max_time": 3.0},
            "robot": {"qpos": [0.5, 0.5]},  # a list replaces the base's
        },
    )
    sc = load_scenario(path)
    assert sc.name == "fast_nav" and sc.planner.samples == 50
    assert sc.planner.horizon == nav.planner.horizon and sc.world == nav.world
    assert sc.episode.max_time == 3.0 and sc.episode.success == nav.episode.success
    assert sc.robot.qpos == (0.5, 0.5) and sc.hash != nav.hash


def test_null_removes_a_key_of_the_base(user):
    path = _write(
        user, "v", {"base": "pick_place", "name": "v", "planner": {"model": {"attach": None}}}
    )
    assert load_scenario(path).planner.model.attach == ()
    assert load_scenario("pick_place").planner.model.attach


def test_the_name_is_not_inherited(user):
    path = _write(user, "v", {"base": "navigation", "planner": {"samples": 50}})
    with pytest.raises(ConfigError, match=r"v.yaml: name: missing required key"):
        load_scenario(path)


def test_a_base_beside_the_file_is_found_first_and_bases_chain(user):
    _write(
        user / "mine", "slow", {"base": "navigation", "name": "slow", "planner": {"samples": 30}}
    )
    path = _write(
        user / "mine", "slower", {"base": "slow", "name": "slower", "episode": {"max_time": 40.0}}
    )
    sc = load_scenario(path)
    assert (sc.planner.samples, sc.episode.max_time) == (30, 40.0)


def test_a_user_file_may_extend_the_shipped_one_of_its_name(user):
    path = _write(
        user / "configs" / "scenarios",
        "navigation",
        {"base": "navigation", "name": "navigation", "planner": {"samples": 40}},
    )
    assert load_scenario("navigation").planner.samples == 40
    assert load_scenario(path).planner.samples == 40
    assert load_scenario(SCENARIO_DIR / "navigation.yaml").planner.samples != 40


@pytest.mark.parametrize(
    "raw, message",
    [
        (
            {"base": "no_such_scenario", "name": "v"},
            r"v.yaml: base: no such scenario.*no_such_scenario",
        ),
        ({"base": 3, "name": "v"}, r"v.yaml: base: not a scenario name or path"),
        ({"base": "v", "name": "v"}, r"v.yaml: base: a scenario cannot be its own base"),
        (
            {"base": "navigation", "name": "v", "planner": {"sample": 5}},
            r"v.yaml: planner.sample: unknown key",
        ),
    ],
)
def test_a_bad_base_or_key_names_the_file(user, raw, message):
    path = _write(user, "v", raw)
    with pytest.raises(ConfigError, match=message):
        load_scenario(path)


def test_a_loop_of_bases_is_an_error(user):
    _write(user, "a", {"base": "b", "name": "a"})
    path = _write(user, "b", {"base": "a", "name": "b"})
    with pytest.raises(ConfigError, match=r"base: a scenario cannot be its own base"):
        load_scenario(path)


def test_the_shipped_lab_variants_change_only_the_planner():
    for name, base in (
        ("pick_place_lab", "pick_place"),
        ("pick_place_reactive_lab", "pick_place_reactive"),
    ):
        lab, nominal = load_scenario(name), load_scenario(base)
        assert {
            k: v for k, v in lab.raw.items() if k not in ("name", "description", "planner")
        } == {k: v for k, v in nominal.raw.items() if k not in ("name", "description", "planner")}
        assert lab.planner.tracking.held_filter < 1.0 and lab.planner.confirm
        assert nominal.planner.tracking.held_filter == 1.0
