"""Errors up front: every error of a scenario file at once, before any process starts.

``m3p2i check`` and ``m3p2i run`` merge what the world (``server.world_check``) and the
planner (``planner_client.planner_check``) find: load-time faults (types, unknown keys) and the
names only the compiled model or the planner's registries can confirm (frames, actuators, cost
terms).
"""

from __future__ import annotations

import copy

import pytest
import yaml
from typer.testing import CliRunner

import shared.config
from m3p2i.cli import app
from planner_client import planner_check
from server import world_check as server_check
from shared.config import ConfigError, ConfigErrors
from shared.frames import FrameResolver
from shared.scenario import SCENARIO_DIR, load_scenario, parse_scenario, read_scenario
from shared.scene import compile_model


def _nav() -> dict:
    return yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())


def _write(tmp_path, raw: dict):
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _three_faults() -> dict:
    """A misspelt frame (model check, world), an unknown cost term (planner registry) and a
    bad weight (load time)."""
    raw = _nav()
    raw["episode"]["success"].append({"near": {"a": "robot", "b": "gaol", "within": 0.1}})
    terms = raw["objectives"]["navigate"]["terms"]
    terms[0]["weight"] = "heavy"
    terms[1]["term"] = "contact_forse"
    return raw


FAULTS = (
    "episode.success[1].near.b: no body named 'gaol'",
    "objectives.navigate.terms[1].term: unknown cost term",
    "objectives.navigate.terms[0].weight: wrong type",
)


def test_m3p2i_check_reports_every_fault_of_a_file_at_once(tmp_path):
    result = CliRunner().invoke(app, ["check", str(_write(tmp_path, _three_faults()))])
    assert result.exit_code == 2, result.output
    for fault in FAULTS:
        assert fault in result.output
    assert "3 errors" in result.output


def test_m3p2i_run_reports_every_fault_before_starting_anything(tmp_path):
    run_dir = tmp_path / "run"
    result = CliRunner().invoke(
        app, ["run", str(_write(tmp_path, _three_faults())), "--run-dir", str(run_dir)]
    )
    assert result.exit_code == 2, result.output
    for fault in FAULTS:
        assert fault in result.output
    assert not run_dir.exists()  # neither process was started
    assert "planner exited" not in result.output


def test_m3p2i_check_accepts_a_sound_file():
    result = CliRunner().invoke(app, ["check", "navigation"])
    assert result.exit_code == 0, result.output
    assert result.output.strip().endswith("ok")


@pytest.mark.parametrize("path", sorted(SCENARIO_DIR.glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_scenarios_pass_both_checks(path):
    assert server_check.scenario_errors(path) == []
    assert planner_check.scenario_errors(path) == []


def test_each_side_checks_what_it_uses(tmp_path):
    path = _write(tmp_path, _three_faults())
    world = "\n".join(str(e) for e in server_check.scenario_errors(path))
    planner = "\n".join(str(e) for e in planner_check.scenario_errors(path))
    assert FAULTS[0] in world and FAULTS[1] not in world  # the world has no cost terms
    assert FAULTS[1] in planner and FAULTS[0] not in planner
    assert FAULTS[2] in world and FAULTS[2] in planner  # a load error: both see it


def test_loading_collects_every_load_time_error():
    raw = _nav()
    raw["episode"]["max_time"] = -1
    raw["planner"]["samples"] = 0
    raw["objectives"]["navigate"]["terms"][2]["weight"] = "x"
    raw["surprise"] = 1
    with pytest.raises(ConfigErrors) as info:
        parse_scenario(raw, "test.yaml")
    paths = [e.path for e in info.value.errors]
    assert paths == [
        "episode.max_time",
        "planner.samples",
        "objectives.navigate.terms[2].weight",
        "surprise",
    ]
    assert str(info.value).count("test.yaml: ") == 4


def test_one_error_is_still_a_plain_config_error():
    raw = _nav()
    raw["episode"]["max_time"] = -1
    with pytest.raises(ConfigError) as info:
        parse_scenario(raw, "test.yaml")
    assert not isinstance(info.value, ConfigErrors)
    assert info.value.path == "episode.max_time"


def test_a_faulty_object_still_declares_its_name(tmp_path):
    # the file's model cannot be built, but the success test's 'goal' is the faulty object's
    # name: a frame check against a model without it would only mislead
    raw = _nav()
    raw["world"]["objects"][3]["shape"] = "cone"  # the goal marker
    reading = read_scenario(_write(tmp_path, raw))
    assert not reading.model_ok
    errors = server_check.scenario_errors(_write(tmp_path, raw))
    assert [e.path for e in errors] == ["world.objects[3].shape"]


def test_a_misspelt_frame_is_reported_beside_a_fault_that_stops_the_model(tmp_path):
    # the arena's type error means no model of the file; the objective's frame is still looked
    # up, against the robot's bodies and sites and the objects the world declares
    raw = _nav()
    raw["world"]["arena"]["half_size"] = "big"
    raw["objectives"]["navigate"]["terms"][0]["b"] = "gaol"
    path = _write(tmp_path, raw)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert "world.arena.half_size: wrong type" in result.output
    assert "objectives.navigate.terms[0].b" in result.output and "'gaol'" in result.output
    assert "2 errors" in result.output
    planner = [str(e) for e in planner_check.scenario_errors(path)]
    assert len(planner) == 2 and "one of: robot" in planner[1] and "goal" in planner[1], planner


def test_names_of_a_faulty_world_are_checked_against_what_it_declares(tmp_path):
    # a faulty object still declares its name; the walls of a faulty arena are still there;
    # the world's other faults are all reported, not only the first
    raw = _nav()
    raw["world"]["arena"]["half_size"] = -1
    raw["world"]["objects"][0]["shape"] = "cone"  # block_a
    raw["episode"]["success"].append({"near": {"a": "robot", "b": "block_a", "within": 0.1}})
    raw["episode"]["success"].append({"near": {"a": "wall_north", "b": "pilar", "within": 0.1}})
    errors = server_check.scenario_errors(_write(tmp_path, raw))
    assert [e.path for e in errors] == [
        "world.arena.half_size",
        "world.objects[0].shape",
        "episode.success[2].near.b",
    ], errors


def test_observer_frames_and_pinned_actuators_are_checked_together(tmp_path):
    raw = yaml.safe_load((SCENARIO_DIR / "push_pull_aip.yaml").read_text())
    raw = copy.deepcopy(raw)
    factor = next(iter(raw["observers"]))
    observers = yaml.safe_dump(raw["observers"][factor])
    raw["observers"][factor] = yaml.safe_load(observers.replace("box", "bocks", 1))
    objective = next(o for o in raw["objectives"].values() if "fixed" in o)
    objective["fixed"] = {"sucktion": 1.0}
    errors = [str(e) for e in planner_check.scenario_errors(_write(tmp_path, raw))]
    assert any(f"observers.{factor}" in e and "'bocks'" in e for e in errors), errors
    assert any("fixed.sucktion: unknown actuator" in e for e in errors), errors


def test_valid_frame_names_are_listed_once():
    sc = read_scenario("navigation").scenario
    names = FrameResolver(compile_model(sc), "robot").names()
    assert names.count("robot") == 1 and len(names) == len(set(names))


def test_an_eta_window_beyond_the_samples_per_mode_is_a_load_error(tmp_path):
    # η counts the samples that matter: a mode of 5 samples can never reach η_l = 10
    raw = _nav()
    raw["planner"]["samples"] = 5
    raw["planner"]["mppi"]["eta_bounds"] = [10.0, 30.0]
    errors = [str(e) for e in planner_check.scenario_errors(_write(tmp_path, raw))]
    assert len(errors) == 1, errors
    assert "broken.yaml: planner.mppi.eta_bounds:" in errors[0]
    assert "planner.samples = 5" in errors[0], errors


def test_an_arena_wall_thickness_is_read_with_a_warning_and_changes_nothing(monkeypatch):
    # walls are planes: world.arena.wall_thickness, accepted from older files, warns once
    monkeypatch.setattr(shared.config, "_WARNED", set())
    raw = _nav()
    old = copy.deepcopy(raw)
    old["world"]["arena"]["wall_thickness"] = 0.1
    with pytest.warns(FutureWarning, match=r"world.arena.wall_thickness \(in old.yaml\).*remove"):
        sc = parse_scenario(old, "old.yaml")
    assert sc.world.arena == parse_scenario(raw, "new.yaml").world.arena


@pytest.mark.parametrize(
    "mppi, key, says",
    [
        ({"lambda_inti": 1.0}, "planner.mppi.lambda_inti", "unknown key"),
        ({"gamma": 1.5}, "planner.mppi.gamma", "must be in (0, 1]"),
        ({"sampling": "sobol"}, "planner.mppi.sampling", "gaussian, halton"),
        ({"savgol_window": 4}, "planner.mppi.savgol_window", "odd"),
        ({"savgol_window": 5, "savgol_order": 5}, "planner.mppi.savgol_order", "below"),
        ({"u_min": [1.0, 1.0], "u_max": [0.0, 2.0]}, "planner.mppi.u_max", "above u_min"),
        ({"noise_sigma": [0.1, -0.1]}, "planner.mppi.noise_sigma", "> 0"),
        ({"keep_best": "yes"}, "planner.mppi.keep_best", "keep_best"),
    ],
)
def test_an_mppi_fault_is_found_at_load_by_both_processes(tmp_path, mppi, key, says):
    # planner.mppi is a section like any other: the world side learns of a typo too
    raw = _nav()
    raw["planner"]["mppi"] = mppi
    path = _write(tmp_path, raw)
    for errors in (server_check.scenario_errors(path), planner_check.scenario_errors(path)):
        assert [e.path for e in errors] == [key], errors
        assert says in str(errors[0]) and "broken.yaml" in str(errors[0]), errors[0]


def test_m3p2i_check_names_an_mppi_fault_once(tmp_path):
    # what both processes found, merged (each starts with --check: ~2 s, so one case here)
    raw = _nav()
    raw["planner"]["mppi"] = {"gamma": 1.5}
    path = _write(tmp_path, raw)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert result.output.count("planner.mppi.gamma") == 1, result.output


def test_mppi_keys_reach_the_planner_as_the_file_gives_them():
    # typed at load, the values stay the file's (a list as a tuple): the same MPPIConfig
    from planner_client.problem import build_problem, mppi_config

    sc = load_scenario("push_pull")
    cfg = mppi_config(sc, build_problem(sc).model)
    assert sc.planner.mppi.given() == {"eta_bounds": (3.0, 10.0), "savgol_window": 5}
    assert cfg.eta_bounds == (3.0, 10.0) and cfg.savgol_window == 5 and cfg.horizon == 15
