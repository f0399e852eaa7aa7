"""Robots declared in files: a robot that is not shipped, in a user's folder, runs a scenario
without any Python edit; robot files are validated against their MJCF at load, with the file,
the key and the value in every error; the shipped robots are such files."""

from __future__ import annotations

import functools

import pytest
import yaml
from typer.testing import CliRunner

from m3p2i.cli import app
from planner_client.build import build_controller
from server.inprocess import run_episode
from shared.config import ConfigError
from shared.robots import ROBOT_DIR, ROBOTS, get_robot, load_robot
from shared.scenario import load_scenario, read_scenario
from tests.user_folder import TWO_LINK, TWO_LINK_XML, reach, user_folder


@pytest.fixture
def lab(tmp_path, monkeypatch):
    """The user's folder as M3P2I_SCENARIOS names it, run from elsewhere."""
    path = user_folder(tmp_path / "lab")
    monkeypatch.setenv("M3P2I_SCENARIOS", str(path.parent))
    monkeypatch.chdir(tmp_path)
    return path


def test_a_robot_of_the_users_runs_a_scenario_from_the_users_folder(lab):
    # lock-step, in one process: the arm's tip reaches the target on three seeds
    planner = functools.partial(build_controller, threads=2)
    for seed in range(3):
        result = run_episode("reach", planner, seed=seed)
        assert result.status == "success", (seed, result.summary)
        assert result.summary["metrics"]["position_error"] <= 0.03


def test_the_users_robot_is_found_by_name_and_listed(lab):
    spec = get_robot("two_link")
    assert spec.path == lab.parent.parent / "robots" / "two_link.xml"
    assert spec.ctrl_units == ("rad/s", "rad/s") and spec.safe_ctrl == (0.0, 0.0)
    assert not spec.shipped
    assert {"two_link", "panda", "point_robot"} <= set(ROBOTS)
    listed = CliRunner().invoke(app, ["list", "robots"])
    assert listed.exit_code == 0, listed.output
    assert "two_link" in listed.output and "a two-link planar arm" in listed.output


def test_a_robot_is_named_by_its_file_or_declared_in_the_scenario(tmp_path):
    path = user_folder(tmp_path)
    by_file = reach(robot={"model": "../robots/two_link.yaml", "qpos": [0.0, 0.5]})
    path.write_text(yaml.safe_dump(by_file, sort_keys=False))
    assert load_scenario(path).robot.spec.ctrl_names == ("shoulder_vel", "elbow_vel")
    inline = reach(robot={**TWO_LINK, "mjcf": "../robots/two_link.xml", "qpos": [0.0, 0.5]})
    path.write_text(yaml.safe_dump(inline, sort_keys=False))
    sc = load_scenario(path)
    assert sc.robot.model == "two_link" and sc.robot.spec.frame == "site:tip"
    assert sc.robot.qpos == (0.0, 0.5)


def test_a_users_robot_file_is_part_of_the_scenarios_hash(tmp_path):
    path = user_folder(tmp_path)
    before = load_scenario(path).hash
    robot = path.parent.parent / "robots" / "two_link.yaml"
    robot.write_text(yaml.safe_dump({**TWO_LINK, "safe_ctrl": [0.1, 0.0]}, sort_keys=False))
    assert load_scenario(path).hash != before  # the two processes must agree on it too


def _errors(tmp_path, robot: dict | None = None, scenario: dict | None = None) -> str:
    path = user_folder(tmp_path, robot, scenario)
    reading = read_scenario(path)
    return "\n".join(str(e) for e in reading.errors)


def test_a_control_the_mjcf_lacks_is_named_with_the_mjcf(tmp_path):
    robot = {**TWO_LINK, "controls": {"shoulder_vel": "rad/s", "elbo_vel": "rad/s"}}
    text = _errors(tmp_path, robot)
    assert "two_link.yaml: controls.elbo_vel: no actuator 'elbo_vel' in" in text
    assert "two_link.xml" in text and "shoulder_vel, elbow_vel" in text


@pytest.mark.slow
def test_m3p2i_check_names_the_control_and_the_mjcf(tmp_path):
    # both processes' --check read the robot file (~8 s of CPU for the two of them)
    robot = {**TWO_LINK, "controls": {"shoulder_vel": "rad/s", "elbo_vel": "rad/s"}}
    path = user_folder(tmp_path, robot)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert "controls.elbo_vel: no actuator 'elbo_vel'" in result.output
    assert str(path.parent.parent / "robots" / "two_link.xml") in result.output


@pytest.mark.parametrize(
    "change, fault",
    [
        ({"controls": {"elbow_vel": "rad/s", "shoulder_vel": "rad/s"}}, "controls: not the actuat"),
        ({"controls": {"shoulder_vel": "rad/s"}}, "(elbow_vel not listed)"),
        (
            {"controls": {"shoulder_vel": "deg/s", "elbow_vel": "rad/s"}},
            "shoulder_vel: unknown unit",
        ),
        ({"frame": "site:tp"}, "frame: no site 'tp' in"),
        ({"frame": "hand"}, "frame: no body 'hand' in"),
        ({"mjcf": "arm.xml"}, "mjcf: no such MJCF file"),
        ({"safe_ctrl": [0.0]}, "safe_ctrl: needs 2 numbers"),
        ({"hold_ctrl": ["gripper"]}, "hold_ctrl[0]: not a control"),
        ({"colour": "red"}, "colour: unknown key"),
    ],
)
def test_robot_file_faults_name_the_file_the_key_and_the_value(tmp_path, change, fault):
    text = _errors(tmp_path, {**TWO_LINK, **change})
    assert "robots/two_link.yaml: " in text and fault in text, text


def test_a_robot_file_missing_a_key_says_which(tmp_path):
    robot = {k: v for k, v in TWO_LINK.items() if k != "frame"}
    assert "two_link.yaml: frame: missing required key" in _errors(tmp_path, robot)


def test_an_unknown_robot_lists_the_known_ones(tmp_path):
    text = _errors(tmp_path, scenario=reach(robot={"model": "ur5e"}))
    assert "robot.model: unknown robot" in text and "point_robot" in text


def test_a_robot_is_named_or_declared_not_both(tmp_path):
    scenario = reach(robot={"model": "two_link", "mjcf": "../robots/two_link.xml"})
    assert "robot.mjcf: a robot is either named (model:) or declared here" in _errors(
        tmp_path, scenario=scenario
    )


def test_the_shipped_robots_are_files_beside_their_mjcf():
    for name in ("point_robot", "point_robot_suction", "diff_drive", "panda"):
        spec = get_robot(name)
        assert spec.shipped and spec.path.parent == ROBOT_DIR
        assert load_robot(ROBOT_DIR / f"{name}.yaml") == spec
    assert get_robot("panda").hold_ctrl == ("gripper",)
    with pytest.raises(KeyError, match="unknown robot 'ur5e'"):
        get_robot("ur5e")
    with pytest.raises(ConfigError):
        load_robot(ROBOT_DIR / "panda.xml")  # an MJCF is not a robot file


def _with_mjcf(root, xml: str, robot: dict | None = None) -> str:
    """The errors of the reach scenario whose arm's MJCF is ``xml``."""
    path = user_folder(root, robot)
    (path.parent.parent / "robots" / "two_link.xml").write_text(xml)
    return "\n".join(str(e) for e in read_scenario(path).errors)


@pytest.mark.parametrize(
    "old, new, fault",
    [
        ('ctrlrange="-1.5 1.5"', 'ctrlrange="1.5 -1.5"', "empty ctrlrange"),
        ('ctrlrange="-1.5 1.5"', 'ctrlrange="nan 1"', "ctrlrange not finite"),
        ('ctrlrange="-1.5 1.5"', 'ctrlrange="0 0"', "empty ctrlrange"),
        ('ctrlrange="-1.5 1.5"', 'ctrlrange="-inf inf"', "ctrlrange not finite"),
        ('ctrlrange="-1.5 1.5"', 'ctrlrange="-1.5 1.5" ctrllimited="false"', "not enforced"),
    ],
)
def test_a_control_without_a_usable_range_is_refused_naming_robot_file_and_actuator(
    tmp_path, old, new, fault
):
    # the planner samples within ctrlrange and the world clips to it: without a range, NaN
    # controls reached the world, or the planner sent zeros until the episode timed out
    text = _with_mjcf(tmp_path, TWO_LINK_XML.replace(old, new))
    assert "robots/two_link.yaml: controls.shoulder_vel: actuator 'shoulder_vel'" in text, text
    assert "two_link.xml" in text and fault in text and "LOW < HIGH" in text, text
    assert "noise_sigma" not in text


def test_a_safe_control_outside_the_range_is_refused(tmp_path):
    text = _errors(tmp_path, {**TWO_LINK, "safe_ctrl": [0.0, 2.0]})
    assert "two_link.yaml: safe_ctrl[1]: outside the ctrlrange of actuator 'elbow_vel'" in text
    assert "[-1.5, 1.5]" in text, text


def test_a_unit_that_does_not_fit_the_actuator_is_refused(tmp_path):
    # a position servo is not driven in rad/s, a velocity servo not in rad
    xml = TWO_LINK_XML.replace('<velocity name="elbow_vel"', '<position kp="5" name="elbow_vel"')
    text = _with_mjcf(tmp_path, xml)
    assert "controls.elbow_vel: actuator 'elbow_vel'" in text
    assert "is a position servo, not driven in rad/s" in text and "m, rad, fraction" in text
    robot = {**TWO_LINK, "controls": {"shoulder_vel": "rad", "elbow_vel": "rad/s"}}
    assert "is a velocity servo, not driven in rad" in _errors(tmp_path, robot)
