"""Shared objective definitions: ``include:`` files of named objectives under
configs/objectives/, and ``extends:`` to start an objective from one of them."""

from __future__ import annotations

import pytest
import yaml

from planner_client import planner_check
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, load_scenario, with_base

LIBRARY = {
    "description": "test objectives",
    "objectives": {
        "go": {
            "terms": [{"term": "distance", "a": "robot", "b": "box", "axes": "xy"}],
            "fixed": {"suction": 0.0},
        },
        "go_hard": {"extends": "go", "terms": [{"term": "velocity", "a": "robot"}]},
    },
}


def _files(tmp_path, library=LIBRARY, objectives=None, include=None):
    lib = tmp_path / "lib.yaml"
    lib.write_text(yaml.safe_dump(library))
    raw = yaml.safe_load((SCENARIO_DIR / "push.yaml").read_text())
    raw["include"] = include or [str(lib)]
    raw["objectives"] = objectives or {
        "push": {
            "extends": "go_hard",
            "terms": [{"term": "control_effort"}],
            "fixed": {"suction": 0.5},
        }
    }
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path, lib


def test_extends_appends_terms_and_updates_fixed(tmp_path):
    path, lib = _files(tmp_path)
    push = load_scenario(path).objectives["push"]
    assert [t.term for t in push.terms] == ["distance", "velocity", "control_effort"]
    assert push.fixed == {"suction": 0.5}
    # each term remembers where it is written, for the planner's error messages
    assert push.terms[0].source == str(lib) and push.terms[0].path == "objectives.go.terms[0]"
    assert push.terms[2].source == str(path) and push.terms[2].path == "objectives.push.terms[0]"


def test_the_hash_covers_the_included_files(tmp_path):
    path, lib = _files(tmp_path)
    before = load_scenario(path).hash
    changed = yaml.safe_load(lib.read_text())
    changed["objectives"]["go"]["terms"][0]["weight"] = 2.0
    lib.write_text(yaml.safe_dump(changed))
    assert load_scenario(path).hash != before


def test_an_unknown_include_names_the_key_and_the_choices(tmp_path):
    path, _ = _files(tmp_path, include=["no_such_objectives"])
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    text = str(info.value)
    assert "include[0]" in text and "no_such_objectives" in text and "push_pull" in text


def test_an_unknown_base_names_the_key_and_the_choices(tmp_path):
    path, _ = _files(tmp_path, objectives={"push": {"extends": "gogo"}})
    with pytest.raises(
        ConfigError, match=r"objectives\.push\.extends: must be one of: go, go_hard \(got .gogo."
    ):
        load_scenario(path)


def test_a_name_defined_in_two_included_files_is_an_error(tmp_path):
    path, lib = _files(tmp_path)
    raw = yaml.safe_load(path.read_text())
    raw["include"] = [str(lib), str(lib)]
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match=r"objectives\.go: defined in two included files"):
        load_scenario(path)


def test_a_fault_in_an_included_file_names_that_file(tmp_path):
    library = {
        "objectives": {
            "go": {"terms": [{"term": "distance", "a": "robot", "b": "bocks"}]},
            "go_hard": {"extends": "go"},
        }
    }
    path, lib = _files(tmp_path, library=library)
    errors = [str(e) for e in planner_check.scenario_errors(path)]
    assert any(
        e.startswith(f"{lib}: objectives.go.terms[0].b: no body named 'bocks'") for e in errors
    ), errors


def test_the_shipped_push_and_pull_are_defined_once():
    """configs/objectives/push_pull.yaml defines them; a scenario extends one and may add terms
    of its own (push_lab_variants weighs the alignment more), but never copies one: an
    alignment term appears only in an objective that extends another."""
    for path in SCENARIO_DIR.glob("*.yaml"):
        raw = with_base(yaml.safe_load(path.read_text()), str(path))
        for name, objective in (raw.get("objectives") or {}).items():
            terms = {t.get("term") for t in objective.get("terms") or []}
            if terms & {"push_align", "pull_align"}:
                assert objective.get("extends"), (path.name, name)
    assert load_scenario("push_pull").objectives["pull"].fixed == {"suction": 1.0}
    assert load_scenario("push_nonholonomic").objectives["push"].fixed == {}
