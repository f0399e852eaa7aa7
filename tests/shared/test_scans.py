"""Sensors' readings on the wire and in the scenario (shared/scans.py, shared/protocol.py
version 3, shared/scenario/sensors.py, ``world.objects[].perceived``; docs/protocol.md, "Scans"):
a state carries its scans in version 3 and none in version 2; a malformed reading (NaN ranges,
wrong lengths, absurd poses, an unknown kind) refuses the state with a clear ProtocolError and
never anything else, fuzzed as tests/shared/test_fuzz.py fuzzes the messages; sensor keys are
refused at their edges, naming file, key and value."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from planner_client.perception.rays import rotation, world_points
from shared import protocol as P
from shared.config import ConfigError
from shared.scans import Scan, check_scan
from shared.scenario import parse_scenario
from shared.scenario.sensors import DepthConfig, LidarConfig
from tests.shared.test_fuzz import FUZZ, hostile


def lidar(**over) -> Scan:
    fields = dict(
        name="base_lidar",
        kind="lidar",
        time=0.5,
        pos=np.array([1.0, 2.0, 0.15]),
        quat=np.array([1.0, 0.0, 0.0, 0.0]),
        ranges=np.linspace(0.5, 9.0, 8),
        range_min=0.05,
        range_max=8.0,
        angle_min=-math.pi,
        angle_increment=math.pi / 4,
    )
    return Scan(**(fields | over))


def depth(**over) -> Scan:
    fields = dict(
        name="table_cam",
        kind="depth",
        time=0.4,
        pos=np.array([0.0, 0.0, 3.0]),
        quat=np.array([0.0, 1.0, 0.0, 0.0]),  # turned 180° about x: looking down
        ranges=np.full((6, 8), 3.0),
        range_min=0.1,
        range_max=5.0,
        fovy=58.0,
    )
    return Scan(**(fields | over))


def state(scans) -> P.State:
    return P.State(
        session="s",
        seq=3,
        time=0.5,
        qpos=np.zeros(2),
        qvel=np.zeros(2),
        act=np.zeros(0),
        mocap_pos=np.zeros((1, 3)),
        mocap_quat=np.array([[1.0, 0.0, 0.0, 0.0]]),
        scans=scans,
    )


def raw_state(scans) -> dict:
    return msgpack.unpackb(P.encode(state(scans)), raw=False)


def decode_raw(raw: dict):
    return P.decode(msgpack.packb(raw, use_bin_type=True), expect="state")


# ---------------------------------------------------------------- the wire


def test_version_3_carries_the_scans_and_version_2_none():
    sent = [lidar(), depth()]
    back = P.decode(P.encode(state(sent)), expect="state")
    assert [s.kind for s in back.scans] == ["lidar", "depth"]
    for a, b in zip(sent, back.scans, strict=True):
        assert (a.name, a.time, a.range_min, a.range_max) == (
            b.name,
            b.time,
            b.range_min,
            b.range_max,
        )
        assert np.array_equal(a.ranges, b.ranges) and np.array_equal(a.pos, b.pos)
        assert (a.angle_min, a.angle_increment, a.fovy) == (b.angle_min, b.angle_increment, b.fovy)
    raw = msgpack.unpackb(P.encode(state(sent)), raw=False)
    assert set(raw["scans"][0]) == set(P._SCAN_FIELDS) | {"angle_min", "angle_increment"}
    assert set(raw["scans"][1]) == set(P._SCAN_FIELDS) | {"fovy"}
    v2 = msgpack.unpackb(P.encode(state(sent), 2), raw=False)
    assert v2["v"] == 2 and "scans" not in v2
    assert P.decode(P.encode(state(sent), 2), versions=P.VERSIONS).scans == []
    assert "scans" not in msgpack.unpackb(P.encode(state([])), raw=False)  # none: left out
    frame = msgpack.packb(raw | {"v": 2}, use_bin_type=True)
    with pytest.raises(P.ProtocolError, match=r"state: unknown field\(s\) \['scans'\]"):
        P.decode(frame, versions=P.VERSIONS)  # a version-2 reader never sees scans


def test_a_decoded_reading_is_normalised_and_gives_its_points():
    back = P.decode(P.encode(state([lidar(quat=np.array([1.0005, 0, 0, 0]))])), expect="state")
    scan = back.scans[0]
    assert np.linalg.norm(scan.quat) == pytest.approx(1.0, abs=1e-15)
    assert scan.ranges.dtype == np.float64
    points = world_points(scan)  # 0.5 .. 9 over 8 rays: the last beyond range_max
    assert len(points) == 7
    assert np.allclose(points[0], [1.0 - 0.5, 2.0, 0.15])  # ray 0 at -π: along -x
    assert np.allclose(rotation(depth().quat)[:, 2], [0.0, 0.0, -1.0])


def _scan_case(i: int, key: str, value) -> dict:
    raw = raw_state([lidar(), depth()])
    raw["scans"][i][key] = value
    return raw


@pytest.mark.parametrize(
    "i, key, value, reason",
    [
        (0, "ranges", P.encode_array(np.array([1.0, math.nan])), "ranges: contains NaN or inf"),
        (1, "ranges", P.encode_array(np.full((2, 2), math.inf)), "ranges: contains NaN or inf"),
        (0, "ranges", P.encode_array(np.ones(4097)), "a lidar's are \\[N\\], 1 <= N <= 4096"),
        (0, "ranges", P.encode_array(np.ones(0)), "a lidar's are \\[N\\]"),
        (0, "ranges", P.encode_array(np.ones((2, 3))), "a lidar's are \\[N\\]"),
        (1, "ranges", P.encode_array(np.ones(48)), "a depth image's are \\[height, width\\]"),
        (1, "ranges", P.encode_array(np.ones((241, 320))), "at most 76800 pixels"),
        (0, "ranges", P.encode_array(np.ones(8, dtype=np.int32)), "expected finite floats"),
        (0, "pos", P.encode_array(np.array([1e9, 0.0, 0.0])), "pos: expected \\[3\\] finite"),
        (0, "pos", P.encode_array(np.zeros(2)), "pos: expected \\[3\\]"),
        (0, "quat", P.encode_array(np.zeros(4)), "quat: expected a unit quaternion"),
        (0, "quat", P.encode_array(np.array([2.0, 0, 0, 0])), "norm 2"),
        (0, "quat", P.encode_array(np.ones(3)), "quat: expected a unit quaternion"),
        (0, "kind", "radar", "kind: 'radar' \\(expected one of lidar, depth\\)"),
        (0, "kind", 3, "kind: 3"),
        (0, "fovy", 58.0, "unknown field\\(s\\) for a lidar scan \\['fovy'\\]"),
        (1, "angle_min", 0.0, "unknown field\\(s\\) for a depth scan \\['angle_min'\\]"),
        (0, "range_min", 8.0, "range_min 8.0, range_max 8.0"),
        (0, "range_min", -0.1, "expected 0 <= range_min < range_max"),
        (0, "time", -1.0, "time -1.0 s"),
        (0, "time", 1e12, "time 1000000000000.0 s"),
        (0, "name", "x" * 65, "name: expected a string of 1 to 64"),
        (0, "name", "", "name: expected a string of 1 to 64"),
        (0, "angle_increment", 7.0, "within ±2π"),
        (1, "fovy", 180.0, "fovy 180.0"),
        (0, "range_max", "far", "range_max: expected a finite number"),
    ],
)
def test_a_malformed_reading_refuses_the_state_naming_it(i, key, value, reason):
    with pytest.raises(P.ProtocolError, match=rf"state\.scans\[{i}\].*{reason}"):
        decode_raw(_scan_case(i, key, value))


def test_a_missing_field_or_too_many_readings_refuse_the_state():
    raw = raw_state([lidar()])
    del raw["scans"][0]["angle_increment"]
    with pytest.raises(P.ProtocolError, match=r"missing field\(s\) \['angle_increment'\]"):
        decode_raw(raw)
    raw = raw_state([lidar()])
    raw["scans"] = raw["scans"] * (P.MAX_SCANS + 1)
    with pytest.raises(P.ProtocolError, match="at most 64 scan maps"):
        decode_raw(raw)
    for bad in ({"k": 1}, [1], "scan"):
        with pytest.raises(P.ProtocolError, match=r"state\.scans"):
            decode_raw(raw_state([lidar()]) | {"scans": bad})


def test_check_scan_refuses_what_the_wire_refuses():
    assert check_scan(lidar()).name == "base_lidar"
    for bad in (
        lidar(kind="sonar"),
        lidar(ranges=np.array([1.0, math.nan])),
        lidar(pos=np.array([math.inf, 0, 0])),
        depth(ranges=np.ones(5)),
        depth(fovy=0.0),
    ):
        with pytest.raises(ValueError):
            check_scan(bad)


# ---------------------------------------------------------------- fuzz

SCAN_KEYS = sorted(set(P._SCAN_FIELDS) | {"angle_min", "angle_increment", "fovy", "extra"})


@st.composite
def hostile_scans(draw):
    """A valid state with a lidar and a depth reading, one to three of their values (or their
    arrays' keys) replaced by hostile ones, or a reading replaced whole."""
    raw = raw_state([lidar(), depth()])
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, 1))
        if draw(st.integers(0, 9)) == 0:
            raw["scans"][i] = draw(hostile)
            continue
        scan = raw["scans"][i]
        if not isinstance(scan, dict):
            continue
        key = draw(st.sampled_from(SCAN_KEYS))
        value = scan.get(key)
        if isinstance(value, dict) and value.get("nd") and draw(st.booleans()):
            value = dict(value)
            value[draw(st.sampled_from(["dtype", "shape", "data", "nd"]))] = draw(hostile)
            scan[key] = value
        elif draw(st.integers(0, 9)) == 0:
            scan.pop(key, None)
        else:
            scan[key] = draw(hostile)
    return raw


@FUZZ
@given(raw=hostile_scans())
def test_hostile_readings_are_decoded_or_refused(raw):
    try:
        frame = msgpack.packb(raw, use_bin_type=True)
    except (ValueError, OverflowError, TypeError):
        return
    try:
        msg = P.decode(frame, expect="state")
    except P.ProtocolError:
        return
    for scan in msg.scans:  # what a planner may rely on
        assert scan.kind in ("lidar", "depth") and 0 < len(scan.name) <= 64
        assert np.all(np.isfinite(scan.ranges)) and scan.ranges.dtype == np.float64
        assert scan.ranges.ndim == (1 if scan.kind == "lidar" else 2)
        assert 0 <= scan.range_min < scan.range_max and 0 <= scan.time <= P.MAX_WORLD_TIME
        assert scan.pos.shape == (3,) and np.all(np.isfinite(scan.pos))
        assert abs(np.linalg.norm(scan.quat) - 1.0) < 1e-12


# ---------------------------------------------------------------- the scenario's keys


def scenario(sensors=None, objects=None):
    raw = {"base": "navigation", "name": "seen"}
    if sensors is not None:
        raw["sensors"] = sensors
    if objects is not None:
        raw["world"] = {"objects": objects}
    return parse_scenario(raw, "/tmp/seen.yaml")


def test_sensor_keys_take_their_defaults_and_edges():
    sc = scenario(
        [
            {"name": "l", "type": "lidar"},
            {"name": "d", "type": "depth", "pos": [0, 0, 2], "look_at": [1, 0, 0]},
            {"name": "edge", "type": "lidar", "rays": 4096, "fov": 360, "rate": 100},
            {"name": "big", "type": "depth", "width": 320, "height": 240, "fovy": 179.9},
            {"name": "x" * 64, "type": "lidar", "range": [0, 1000], "rate": 0.01},
        ]
    )
    assert sc.sensors[0] == LidarConfig(name="l")
    assert sc.sensors[0].frame == "robot" and sc.sensors[0].range == (0.05, 8.0)
    assert isinstance(sc.sensors[1], DepthConfig) and sc.sensors[1].frame == "world"
    assert [s.name for s in sc.sensors][2:4] == ["edge", "big"]


@pytest.mark.parametrize(
    "sensor, key, value",
    [
        ({"type": "lidar", "rays": 0}, "rays", 0),
        ({"type": "lidar", "rays": 4097}, "rays", 4097),
        ({"type": "lidar", "rays": 10.0}, "rays", 10.0),
        ({"type": "lidar", "fov": 0}, "fov", 0),
        ({"type": "lidar", "fov": 360.5}, "fov", 360.5),
        ({"type": "lidar", "rate": 0}, "rate", 0),
        ({"type": "lidar", "rate": 100.5}, "rate", 100.5),
        ({"type": "lidar", "rate": math.inf}, "rate", math.inf),
        ({"type": "lidar", "range": [1.0, 1.0]}, "range", [1.0, 1.0]),
        ({"type": "lidar", "range": [-0.1, 1.0]}, "range", [-0.1, 1.0]),
        ({"type": "lidar", "range": [0.1, 1001]}, "range", [0.1, 1001]),
        ({"type": "lidar", "range": [0.1]}, "range", [0.1]),
        ({"type": "lidar", "pos": [0, 0]}, "pos", [0, 0]),
        ({"type": "lidar", "name": "x" * 65}, "name", "x" * 65),
        ({"type": "lidar", "frame": 3}, "frame", 3),
        ({"type": "sonar"}, "type", "sonar"),
        ({"type": "lidar", "width": 10}, "width", None),
        ({"type": "depth", "rays": 10}, "rays", None),
        ({"type": "depth", "width": 321, "height": 240}, "width", 321),
        ({"type": "depth", "width": 0}, "width", 0),
        ({"type": "depth", "fovy": 180}, "fovy", 180),
        ({"type": "depth", "euler": [0, 0, 0], "look_at": [1, 0, 0]}, "look_at", [1, 0, 0]),
        ({"type": "depth", "pos": [1, 0, 0], "look_at": [1, 0, 0]}, "look_at", [1.0, 0.0, 0.0]),
        ({"type": "depth", "euler": [0, 0]}, "euler", [0, 0]),
    ],
)
def test_a_sensor_key_beyond_its_edge_is_refused_naming_file_key_and_value(sensor, key, value):
    with pytest.raises(ConfigError) as info:
        scenario([{"name": "s"} | sensor])
    text = str(info.value)
    assert "/tmp/seen.yaml" in text and f"sensors[0].{key}" in text, text
    if value is not None:
        assert repr(value) in text, text


def test_two_sensors_of_one_name_and_a_perceived_marker_are_refused():
    with pytest.raises(ConfigError, match=r"sensors\[1\]\.name: two sensors of one name"):
        scenario([{"name": "s", "type": "lidar"}, {"name": "s", "type": "depth"}])
    box = {"name": "box", "shape": "box", "size": [0.1, 0.1, 0.1], "pos": [1, 1, 0.1]}
    with pytest.raises(ConfigError, match=r"world\.objects\[0\]\.perceived: a visual object"):
        scenario(objects=[box | {"visual": True, "perceived": True}])
    assert scenario(objects=[box | {"perceived": True}]).world.objects[0].perceived
    assert scenario(objects=[box | {"fixed": False, "perceived": True}]).world.objects[0].perceived
