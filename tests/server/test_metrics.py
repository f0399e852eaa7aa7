"""Episode metrics (server/evaluation/metrics.py) on a hand-made episode log with known answers; the
scenario's ``metrics:`` section; the episode plot on the same log."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import yaml

from server.evaluation.metrics import (
    MetricsEvaluator,
    contact_onsets,
    mean_hz,
    orientation_error,
    position_error,
)
from shared.config import ConfigError
from shared.scenario import load_scenario, parse_scenario
from shared.scene import compile_model

SCENARIO = {
    "name": "metrics_fixture",
    "robot": {"model": "point_robot", "qpos": [0.0, 0.0]},
    "world": {
        "timestep": 0.05,
        "arena": {"half_size": 4.0},
        "objects": [
            {
                "name": "box",
                "shape": "box",
                "size": [0.2, 0.2, 0.05],
                "pos": [1.0, 2.0, 0.05],
                "fixed": False,
            },
            {
                "name": "goal",
                "shape": "box",
                "size": [0.2, 0.2, 0.005],
                "pos": [1.3, 2.4, 0.005],
                "visual": True,
            },
            {"name": "obstacle", "shape": "cylinder", "size": [0.3, 0.2], "pos": [-2.0, 0.0, 0.2]},
        ],
    },
    "episode": {
        "max_time": 10.0,
        "success": [{"near": {"a": "box", "b": "goal", "within": 0.1, "axes": "xy"}}],
    },
    "metrics": {
        "orientation": {"a": "box", "b": "goal"},
        "collisions": {"a": "robot", "with": ["obstacle"]},
    },
    "objectives": {"idle": {"terms": [{"term": "control_effort"}]}},
    "modes": ["idle"],
}

# robot x per step: the robot (r = 0.2) touches the obstacle (r = 0.3 at x = -2) when x > -2.5
# and x < -1.5: touching at steps 2-3 and 5 -> two collisions (onsets), not three
ROBOT_X = [0.0, -1.0, -1.6, -1.7, 0.0, -1.8, -0.5]
PLAN_TIMES = [0.01, 0.03, 0.02, 0.02, 0.02, 0.02, 0.02]
BOX_YAW = 30.0


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "metrics_fixture.yaml"
    path.write_text(yaml.safe_dump(SCENARIO))
    return load_scenario(path)


def hand_made_log(scenario, status: str | None = "timeout") -> list[dict]:
    """A log as the server writes it: header, handshake, steps, summary."""
    model = compile_model(scenario)
    half = math.radians(BOX_YAW) / 2
    records = [
        {
            "kind": "header",
            "wall": 100.0,
            "scenario": scenario.name,
            "scenario_hash": scenario.hash,
            "source": scenario.source,
            "seed": 0,
            "initial": [],
        },
        {"kind": "event", "wall": 101.0, "what": "handshake"},
    ]
    for i, (x, pt) in enumerate(zip(ROBOT_X, PLAN_TIMES)):
        qpos = np.zeros(model.nq)
        qpos[:2] = (x, 0.0)
        qpos[2:9] = (1.0, 2.0, 0.05, math.cos(half), 0.0, 0.0, math.sin(half))
        records.append(
            {
                "kind": "step",
                "wall": 101.5 + 0.5 * i,
                "seq": i + 1,
                "time": 0.05 * (i + 1),
                "qpos": qpos.tolist(),
                "qvel": [0.0] * model.nv,
                "mocap_pos": model.body_pos[model.body_mocapid >= 0].tolist(),
                "mocap_quat": model.body_quat[model.body_mocapid >= 0].tolist(),
                "plan_time": pt,
            }
        )
    if status:
        records.append({"kind": "summary", "wall": 106.0, "status": status})
    return records


def test_metrics_of_a_hand_made_log_have_the_known_values(scenario):
    m = MetricsEvaluator(scenario).evaluate(hand_made_log(scenario))
    assert m.status == "timeout" and not m.success
    assert m.position_error == pytest.approx(0.5)  # |(1, 2) - (1.3, 2.4)|
    assert m.orientation_error == pytest.approx(2 - math.sqrt(3))  # 30 deg about z, paper Eq. 33
    assert m.collisions == 2
    assert m.time == pytest.approx(0.35)
    assert m.wall_time == pytest.approx(104.5 - 101.0)  # handshake -> last step
    assert m.planner_hz == pytest.approx(1 / np.mean(PLAN_TIMES))
    assert m.steps == len(ROBOT_X)


def test_status_argument_and_unfinished_logs(scenario):
    ev = MetricsEvaluator(scenario)
    assert ev.evaluate(hand_made_log(scenario), status="success").success
    cut = ev.evaluate(hand_made_log(scenario, status=None))
    assert cut.status == "unfinished" and cut.position_error == pytest.approx(0.5)
    empty = ev.evaluate(hand_made_log(scenario)[:1])
    assert empty.steps == 0 and empty.position_error is None and empty.collisions == 0


def test_pure_maths():
    assert position_error([0, 0, 0], [3, 4, 12]) == pytest.approx(13.0)
    assert position_error([0, 0, 0], [3, 4, 12], "xy") == pytest.approx(5.0)
    flip = np.diag([1.0, -1.0, -1.0])  # a cube turned upside down: equivalent
    assert orientation_error(np.eye(3), flip) == pytest.approx(0.0)
    assert contact_onsets([]) == 0
    assert contact_onsets([True, True, False, True, False, False, True]) == 3
    assert mean_hz([]) == 0.0 and mean_hz([0.0, 0.5]) == pytest.approx(2.0)


def test_default_position_metric_is_the_first_near_success_predicate(scenario):
    pair = scenario.metrics.position
    assert (pair.a, pair.b, pair.axes) == ("box", "goal", "xy")
    nav = load_scenario("navigation").metrics
    assert nav.position.a == "robot" and nav.orientation is None and nav.collisions is None


def test_at_pose_success_gives_position_with_offset_and_orientation(tmp_path):
    """Pick-and-place judges success on at_pose (goal = b + offset, paper Eq. 26): the metrics
    default to the same frames, offset included."""
    raw = {
        **SCENARIO,
        "metrics": {"collisions": {"a": "robot", "with": ["obstacle"]}},
        "episode": {
            "max_time": 10.0,
            "success": [
                {
                    "at_pose": {
                        "a": "box",
                        "b": "goal",
                        "offset": [0.0, 0.0, 0.045],
                        "within": 0.01,
                        "orientation": 0.01,
                    }
                }
            ],
        },
    }
    path = tmp_path / "at_pose.yaml"
    path.write_text(yaml.safe_dump(raw))
    sc = load_scenario(path)
    assert sc.metrics.position.offset == (0.0, 0.0, 0.045) and sc.metrics.position.axes == "xyz"
    assert (sc.metrics.orientation.a, sc.metrics.orientation.b) == ("box", "goal")
    m = MetricsEvaluator(sc).evaluate(hand_made_log(sc))
    assert m.position_error == pytest.approx(0.5)  # heights 0.05 vs 0.005 + 0.045 cancel
    assert m.orientation_error == pytest.approx(2 - math.sqrt(3))


@pytest.mark.parametrize(
    "metrics, key",
    [
        ({"position": {"a": "box"}}, "metrics.position.b"),
        ({"position": {"a": "box", "b": "goal", "axes": "zx"}}, "metrics.position.axes"),
        ({"position": {"a": "box", "b": "goal", "offset": [0, 1]}}, "metrics.position.offset"),
        ({"orientation": {"a": "box", "b": "goal", "axes": "xy"}}, "metrics.orientation.axes"),
        ({"collisions": {"a": "robot"}}, "metrics.collisions.with"),
        ({"speed": {}}, "metrics.speed"),
    ],
)
def test_metrics_section_is_parsed_strictly(metrics, key):
    with pytest.raises(ConfigError) as err:
        parse_scenario({**SCENARIO, "metrics": metrics}, "fixture.yaml")
    assert err.value.path == key


def test_unknown_metric_frame_names_the_key(scenario, tmp_path):
    raw = {**SCENARIO, "metrics": {"collisions": {"a": "robot", "with": ["ghost"]}}}
    path = tmp_path / "ghost.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError) as err:
        MetricsEvaluator(load_scenario(path))
    assert err.value.path == "metrics.collisions.with[0]" and "ghost" in str(err.value)


def test_robot_collisions_cover_the_whole_robot_tree(tmp_path):
    """'robot' is every body under the robot's root (a Panda's links and fingers), not only the
    body of its frame (the grasp site on the hand)."""
    raw = {
        **SCENARIO,
        "robot": {"model": "panda"},
        "episode": {
            "max_time": 1.0,
            "success": [{"near": {"a": "robot", "b": "goal", "within": 0.01}}],
        },
        "metrics": {"collisions": {"a": "robot", "with": ["obstacle"]}},
    }
    path = tmp_path / "panda.yaml"
    path.write_text(yaml.safe_dump(raw))
    ev = MetricsEvaluator(load_scenario(path))
    m = ev.model
    hand = m.site_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "grasp")]
    robot_root = m.body_rootid[hand]
    expected = m.body_rootid[m.geom_bodyid] == robot_root
    assert expected.sum() > 8 and np.array_equal(ev._geoms_a, expected)
    obstacle = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "obstacle")
    assert np.array_equal(ev._geoms_b, m.geom_bodyid == obstacle)


def test_the_plot_draws_the_identified_model_against_the_worlds(scenario, tmp_path):
    """Steps with the planner's estimate (planner.model.variants) and a header with the world's
    factors: one series per estimated factor, NaN before the first estimate, the truth beside."""
    from m3p2i.plots import episode_series, plot_episode

    records = hand_made_log(scenario)
    records[0]["faults_mismatch"] = {"mass": {"box": 1.5}, "gain": {"vel_x": 0.8}}
    steps = [r for r in records if r["kind"] == "step"]
    for i, step in enumerate(steps[1:]):
        step["model"] = {"mass.box": 1.0 + 0.1 * i}  # as the world logs Command.model
    series = episode_series(scenario, records)
    assert list(series.model) == ["mass.box"] and series.truth["mass.box"] == 1.5
    values = series.model["mass.box"]
    assert np.isnan(values[0]) and values[1:].tolist() == pytest.approx(
        [1.0 + 0.1 * i for i in range(len(steps) - 1)]
    )
    assert plot_episode(series, tmp_path / "episode.png").stat().st_size > 10_000
    plain = episode_series(scenario, hand_made_log(scenario))
    assert plain.model == {} and plain.truth == {}


def test_plot_of_the_hand_made_log(scenario, tmp_path):
    from m3p2i.plots import cos_rog, episode_series, plot_episode

    series = episode_series(scenario, hand_made_log(scenario))
    assert series.obj is not None and series.time.shape == (len(ROBOT_X),)
    np.testing.assert_allclose(series.obj[-1, :2], [1.0, 2.0], atol=1e-9)
    out = plot_episode(series, tmp_path / "episode.png")
    assert out.stat().st_size > 10_000
    # robot behind the object as seen from the goal: cos = -1 (pushing); in front: +1 (pulling)
    obj, goal = np.zeros((2, 3)), np.array([[1.0, 0, 0], [1.0, 0, 0]])
    robot = np.array([[-1.0, 0, 0], [0.5, 0, 0]])
    np.testing.assert_allclose(cos_rog(robot, obj, goal), [-1.0, 1.0])
