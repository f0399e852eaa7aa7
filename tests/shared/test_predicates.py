"""Predicates of the pick-and-place observers and success tests (paper Eqs. 23-26): at_pose,
gripper_width_between and the all combinator, on hand-set MuJoCo states."""

from __future__ import annotations

import math

import mujoco
import pytest

from shared.config import ConfigError, Section
from shared.frames import FrameResolver
from shared.predicates import WorldView, check_frames, parse_predicate

# Two free 5 cm cubes and a "hand" with two fingertip sites 6 cm apart.
MJCF = """
<mujoco>
  <worldbody>
    <body name="cube_a" pos="0 0 1.075">
      <freejoint/><geom type="box" size="0.025 0.025 0.025"/>
    </body>
    <body name="cube_b" pos="0 0 1.025">
      <freejoint/><geom type="box" size="0.025 0.025 0.025"/>
    </body>
    <body name="hand" pos="0 0 1.3">
      <site name="left" pos="0 0.03 0"/>
      <site name="right" pos="0 -0.03 0"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_string(MJCF)


def world(model, a_pos=(0, 0, 1.075), a_yaw_deg=0.0):
    data = mujoco.MjData(model)
    data.qpos[:3] = a_pos
    half = math.radians(a_yaw_deg) / 2
    data.qpos[3:7] = [math.cos(half), 0, 0, math.sin(half)]
    mujoco.mj_forward(model, data)
    return WorldView(data, {})


def bound(model, spec: dict):
    pred = parse_predicate(Section(spec, "test.yaml", "p"))
    return pred.bind(FrameResolver(model, "hand"))


ON_B = {"a": "cube_a", "b": "cube_b", "offset": [0, 0, 0.05], "within": 0.01, "orientation": 0.01}


def test_at_pose_position_with_offset(model):
    p = bound(model, {"at_pose": ON_B})
    assert p(world(model))  # exactly on top of cube B
    assert p(world(model, (0.009, 0, 1.075)))  # 9 mm off: inside 1 cm (paper Eq. 26)
    assert not p(world(model, (0.011, 0, 1.075)))
    assert not p(world(model, (0, 0, 1.025 + 0.05 + 0.0101)))
    m = p.measures(world(model, (0.003, 0.004, 1.075)))
    assert m["position error cube_a-cube_b"] == pytest.approx(0.005)


def test_at_pose_orientation_uses_the_symmetric_metric(model):
    p = bound(model, {"at_pose": ON_B})
    assert p(world(model, a_yaw_deg=90.0))  # a cube's symmetry: aligned
    assert p(world(model, a_yaw_deg=5.0))  # phi = 2(1 - cos 5deg) = 0.0076
    assert not p(world(model, a_yaw_deg=7.0))  # phi = 0.0149
    phi = p.measures(world(model, a_yaw_deg=7.0))["orientation error cube_a-cube_b"]
    assert phi == pytest.approx(2 * (1 - math.cos(math.radians(7.0))), abs=1e-9)
    position_only = bound(
        model, {"at_pose": {"a": "cube_a", "b": "cube_b", "offset": [0, 0, 0.05], "within": 0.01}}
    )
    assert position_only(world(model, a_yaw_deg=30.0))


def test_gripper_width_between_is_strict_and_validated(model):
    view = world(model)
    assert bound(
        model,
        {
            "gripper_width_between": {
                "left": "site:left",
                "right": "site:right",
                "low": 0.05,
                "high": 0.065,
            }
        },
    )(view)
    assert not bound(
        model,
        {
            "gripper_width_between": {
                "left": "site:left",
                "right": "site:right",
                "low": 0.06,
                "high": 0.065,
            }
        },
    )(view)
    p = bound(
        model,
        {
            "gripper_width_between": {
                "left": "site:left",
                "right": "site:right",
                "low": 0.0,
                "high": 0.07,
            }
        },
    )
    assert p.measures(view) == {"gripper width": pytest.approx(0.06)}
    with pytest.raises(
        ConfigError, match=r"p\.gripper_width_between\.high: must be greater than low"
    ):
        bound(
            model,
            {
                "gripper_width_between": {
                    "left": "site:left",
                    "right": "site:right",
                    "low": 0.07,
                    "high": 0.05,
                }
            },
        )


def test_all_holds_when_every_part_does_and_merges_measures(model):
    spec = {
        "all": [
            {"at_pose": ON_B},
            {
                "gripper_width_between": {
                    "left": "site:left",
                    "right": "site:right",
                    "low": 0.05,
                    "high": 0.065,
                }
            },
        ]
    }
    p = bound(model, spec)
    assert p(world(model))
    assert not p(world(model, (0.02, 0, 1.075)))
    assert set(p.measures(world(model))) == {
        "position error cube_a-cube_b",
        "orientation error cube_a-cube_b",
        "gripper width",
    }
    nested = bound(model, {"all": [spec, {"near": {"a": "cube_a", "b": "cube_b", "within": 0.06}}]})
    assert nested(world(model)) and not nested(world(model, (0.02, 0, 1.075)))


def test_all_errors_name_the_key(model):
    with pytest.raises(ConfigError, match=r"p\.all: needs at least one predicate"):
        bound(model, {"all": []})
    with pytest.raises(ConfigError, match=r"p\.all: wrong type"):
        bound(model, {"all": {"near": {}}})
    pred = parse_predicate(
        Section(
            {
                "all": [
                    {"near": {"a": "cube_a", "b": "cube_b", "within": 1}},
                    {"near": {"a": "cube_a", "b": "cube_c", "within": 1}},
                ]
            },
            "test.yaml",
            "p",
        )
    )
    with pytest.raises(
        ConfigError, match=r"observers\.x\.all\[1\]\.near\.b: no body named 'cube_c'"
    ):
        check_frames(pred, FrameResolver(model, "hand"), "test.yaml", "observers.x")


def test_at_pose_reads_both_frames_rotations(model):
    # cube B turned, cube A not: misaligned by B's yaw
    data = mujoco.MjData(model)
    data.qpos[:7] = [0, 0, 1.075, 1, 0, 0, 0]
    half = math.radians(20) / 2
    data.qpos[7:14] = [0, 0, 1.025, math.cos(half), 0, 0, math.sin(half)]
    mujoco.mj_forward(model, data)
    p = bound(model, {"at_pose": ON_B})
    assert not p(WorldView(data, {}))
    expected = 2 * (1 - math.cos(math.radians(20)))
    assert p.measures(WorldView(data, {}))["orientation error cube_a-cube_b"] == pytest.approx(
        expected, abs=1e-9
    )


def test_far_keeps_its_distance_as_beyond_and_negates_near(model):
    far = parse_predicate(
        Section({"far": {"a": "cube_a", "b": "cube_b", "beyond": 0.04}}, "test.yaml", "p")
    )
    assert far.beyond == 0.04 and not hasattr(far, "within")
    resolve = FrameResolver(model, "hand")
    assert far.bind(resolve)(world(model))  # cubes 5 cm apart
    assert not far.bind(resolve)(world(model, a_pos=(0, 0, 1.05)))  # 2.5 cm apart
    assert far.bind(resolve).measures(world(model)) == pytest.approx(
        {"distance cube_a-cube_b": 0.05}
    )
