"""The world's range sensors (server/sensors.py) and the objects only they show
(``world.objects[].perceived``): a lidar's and a depth camera's readings equal the analytic
distances to known boxes and cylinders along the rays their documented geometry defines
(shared/scans.py), the robot and markers are no return, readings come at their rate; the
planner's model lacks the perceived objects and nothing of theirs but the scans reaches it; the
scan faults apply, repeatably; the world serves readings in protocol 3 and none to a version-2
planner."""

from __future__ import annotations

import math
import time

import msgpack
import mujoco
import numpy as np
import pytest
import yaml
import zmq
from rich.console import Console

from m3p2i.bridge_layout import bridge_layout
from m3p2i.launch import free_port_block
from m3p2i.layout_table import print_layout
from planner_client.build import build_controller
from planner_client.perception.rays import rotation
from planner_client.planner_check import scenario_errors as planner_errors
from planner_client.problem import build_problem
from server.episode import Episode
from server.faults import FaultyWorld
from server.sensors import MAX_PENDING
from server.world import SimWorld
from server.world_check import scenario_errors as world_errors
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scans import Scan, ray_directions
from shared.scenario import parse_scenario
from shared.scenario.faults import PROFILES, FaultConfig
from tests.helpers import start_server, stop

BOX = {"pos": [2.0, 0.3, 0.2], "size": [0.3, 0.5, 0.2], "yaw": 30.0}
CYL = {"pos": [-0.5, -2.0, 0.25], "size": [0.4, 0.25]}
FAR = {"pos": [-8.5, 0.0, 0.2], "size": [0.2, 0.2, 0.2]}  # 8.3 m away: beyond the lidar's 8
ROBOT = (0.2, 0.1, 0.12)  # point_robot's disc: radius, half-height, height of its centre
FLOOR = 5.0  # the floor's half-size without an arena


def scene(box=BOX, sensors=None, **extra) -> dict:
    """A point robot without an arena, a perceived yawed box, a cylinder, a box out of range
    and a tall marker in the lidar's plane."""
    return {
        "name": "seen",
        "robot": {"model": "point_robot", "qpos": [0.0, 0.0]},
        "world": {
            "timestep": 0.05,
            "objects": [
                {"name": "box", "shape": "box", "perceived": True, **box},
                {"name": "cyl", "shape": "cylinder", **CYL},
                {"name": "far", "shape": "box", **FAR},
                {"name": "goal", "shape": "cylinder", "size": [0.3, 0.2], "pos": [0, 2.5, 0.2]}
                | {"visual": True},
            ],
        },
        "sensors": sensors
        if sensors is not None
        else [
            {"name": "lidar", "type": "lidar", "pos": [0, 0, 0.15], "rays": 360, "rate": 10},
            {"name": "cam", "type": "depth", "pos": [1.5, 0.5, 3.0], "look_at": [2.0, 0.0, 0.0]}
            | {"width": 64, "height": 48, "fovy": 60, "range": [0.1, 10.0]},
            {"name": "down", "type": "depth", "pos": [-0.5, -2.0, 2.0], "euler": [180, 0, 0]}
            | {"width": 32, "height": 24, "fovy": 45, "range": [0.1, 10.0], "rate": 5},
        ],
        "episode": {
            "max_time": 10.0,
            "success": [{"near": {"a": "robot", "b": "goal", "within": 0.1}}],
        },
        "objectives": {
            "go": {"terms": [{"term": "distance", "a": "robot", "b": "goal", "weight": 1.0}]}
        },
        "modes": ["go"],
        **extra,
    }


def load(tmp_path, raw: dict, name: str = "seen.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw))
    return parse_scenario(raw, str(path)), path


# ---------------------------------------------------------------- analytic distances


def _yaw(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ray_box(o, d, center, half, yaw=0.0) -> float:
    """Slab test: the distance along unit ``d`` from ``o`` to the box's surface (inf: none)."""
    rot = _yaw(yaw)
    lo, ld = rot.T @ (o - np.asarray(center)), rot.T @ d
    t0, t1 = -math.inf, math.inf
    for k in range(3):
        if abs(ld[k]) < 1e-12:
            if abs(lo[k]) > half[k]:
                return math.inf
            continue
        a, b = (-half[k] - lo[k]) / ld[k], (half[k] - lo[k]) / ld[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0 if t0 <= t1 and t0 >= 0 else math.inf


def ray_cylinder(o, d, center, radius, half) -> float:
    """A vertical cylinder: its side and its two caps."""
    c = np.asarray(center, dtype=float)
    best = math.inf
    p, q = o[:2] - c[:2], d[:2]
    a, b, cc = q @ q, 2 * p @ q, p @ p - radius**2
    if a > 1e-12 and b * b - 4 * a * cc >= 0:
        for t in ((-b - math.sqrt(b * b - 4 * a * cc)) / (2 * a),):
            if t >= 0 and abs(o[2] + t * d[2] - c[2]) <= half:
                best = min(best, t)
    if abs(d[2]) > 1e-12:
        for z in (c[2] - half, c[2] + half):
            t = (z - o[2]) / d[2]
            x = o + t * d
            if t >= 0 and np.linalg.norm(x[:2] - c[:2]) <= radius:
                best = min(best, t)
    return best


def expected(scan: Scan, robot_xy, box=BOX) -> np.ndarray:
    """Each ray's analytic range, or NaN where no return is due (nothing within the band, or
    the robot first)."""
    origin = np.asarray(scan.pos)
    dirs = ray_directions(scan).reshape(-1, 3) @ rotation(scan.quat).T
    out = []
    for d in dirs:
        hits = {
            "box": ray_box(origin, d, box["pos"], box["size"], box["yaw"]),
            "cyl": ray_cylinder(origin, d, CYL["pos"], *CYL["size"]),
            "far": ray_box(origin, d, FAR["pos"], FAR["size"]),
            "robot": ray_cylinder(origin, d, [*robot_xy, ROBOT[2]], ROBOT[0], ROBOT[1]),
        }
        if d[2] < -1e-12:
            t = -origin[2] / d[2]
            if max(abs(origin[:2] + t * d[:2])) <= FLOOR:
                hits["floor"] = t
        what, t = min(hits.items(), key=lambda kv: kv[1])
        ok = what != "robot" and scan.range_min <= t <= scan.range_max
        out.append(t if ok else math.nan)
    return np.array(out).reshape(scan.ranges.shape)


def assert_matches(scan: Scan, want: np.ndarray) -> None:
    hit = ~np.isnan(want)
    assert np.array_equal(scan.hits(), hit), np.argwhere(scan.hits() != hit)[:5]
    assert np.max(np.abs(scan.ranges[hit] - want[hit])) < 1e-6
    assert np.all(scan.ranges[~hit] == scan.range_max + 1.0)  # the world's no return


@pytest.mark.parametrize("robot_xy", [(0.0, 0.0), (0.4, -0.3)])
def test_each_reading_equals_the_analytic_distances_along_its_documented_rays(tmp_path, robot_xy):
    sc, _ = load(tmp_path, scene())
    world = SimWorld(sc, 0)
    world.data.qpos[:2] = robot_xy
    mujoco.mj_forward(world.model, world.data)
    world.sensors.reset()
    world.sensors.update(world.model, world.data)
    lidar, cam, down = world.scans()
    assert (lidar.angle_min, lidar.angle_increment) == (-math.pi, pytest.approx(2 * math.pi / 360))
    assert np.allclose(lidar.pos, [*robot_xy, 0.15]) and np.allclose(lidar.quat, [1, 0, 0, 0])
    assert cam.ranges.shape == (48, 64) and down.ranges.shape == (24, 32)
    for scan in (lidar, cam, down):
        assert_matches(scan, expected(scan, robot_xy))
    # the robot's own disc hides nothing from its lidar; the marker is seen through; the box
    # 8.3 m off is beyond range
    assert lidar.hits().sum() > 30 and not lidar.hits()[180 + 90]  # along +y: the marker
    # the camera's pose as its keys say: at pos, looking at look_at, the image's up towards +z
    axes = rotation(cam.quat)
    look = np.array([0.5, -0.5, -3.0]) / np.linalg.norm([0.5, -0.5, -3.0])
    assert np.allclose(cam.pos, [1.5, 0.5, 3.0]) and np.allclose(axes[:, 2], look)
    assert axes[2, 1] < 0 and abs(axes[2, 0]) < 1e-12  # rows run downwards, columns level
    assert np.allclose(rotation(down.quat), np.diag([1.0, -1.0, -1.0]))  # euler [180, 0, 0]


def test_the_robot_is_no_return_and_readings_come_at_their_rate(tmp_path):
    cam = {"name": "cam", "type": "depth", "pos": [0, 0, 2.0], "euler": [180, 0, 0]}
    sensors = [
        {"name": "l10", "type": "lidar", "pos": [0, 0, 0.15], "rays": 8, "rate": 10},
        {"name": "l3", "type": "lidar", "pos": [0, 0, 0.15], "rays": 8, "rate": 3},
        cam | {"width": 16, "height": 12, "range": [0.1, 10.0], "rate": 100},
    ]
    sc, _ = load(tmp_path, scene(sensors=sensors))
    world = SimWorld(sc, 0)
    taken = [world.scans()]
    for _ in range(25):
        world.step(np.zeros(2))
        taken.append(world.scans())
    times = {n: [round(s.time, 9) for t in taken for s in t if s.name == n] for n in ("l10", "l3")}
    assert times["l10"] == [round(0.1 * k, 9) for k in range(13)]
    assert times["l3"] == [0.0, 0.35, 0.7, 1.0]  # due at k/3 s, taken at the next step
    first_cam = next(s for s in taken[0] if s.name == "cam")
    centre = first_cam.ranges[5:7, 7:9]  # straight below: the robot's disc
    assert not first_cam.hits()[5:7, 7:9].any() and np.all(centre == 11.0)
    assert first_cam.hits()[0].all()  # the floor around it
    for _ in range(MAX_PENDING + 3):  # nobody takes them: the newest four of each are kept
        world.step(np.zeros(2))
    kept = world.scans()
    assert sum(s.name == "cam" for s in kept) == MAX_PENDING
    assert [s.time for s in kept] == sorted(s.time for s in kept)


# ---------------------------------------------------------------- the planner is blind to them


def test_the_planner_lacks_the_perceived_objects_and_reads_nothing_of_them_but_scans(tmp_path):
    near, _ = load(tmp_path, scene(), "near.yaml")
    moved_box = BOX | {"pos": [1.0, -1.5, 0.2], "yaw": -10.0, "size": [0.2, 0.2, 0.2]}
    moved, _ = load(tmp_path, scene(box=moved_box), "moved.yaml")
    world = SimWorld(near, 0).model
    models = [build_problem(sc).model for sc in (near, moved)]
    for model in models:
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "box") == -1
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "box") == -1
        assert model.nmocap == world.nmocap - 1 and model.nq == world.nq
    for name in ("geom_size", "geom_pos", "geom_quat", "body_pos", "body_quat", "geom_type"):
        assert np.array_equal(getattr(models[0], name), getattr(models[1], name)), name
    states = []
    for i, sc in enumerate((near, moved)):
        episode = Episode(sc, 0, tmp_path / f"log{i}.jsonl")
        states.append(episode.publish())
        episode.close()
    a, b = states
    for name in ("qpos", "qvel", "act", "mocap_pos", "mocap_quat"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.mocap_pos.shape == (world.nmocap - 1, 3)
    assert not np.array_equal(a.scans[0].ranges, b.scans[0].ranges)  # only the scans tell
    controller = build_controller(near, threads=2)
    try:
        controller.begin("lockstep", 0.05)
        assert controller.step(a).ctrl.shape == (2,)  # the state fits the planner's model
    finally:
        controller.close()


def test_a_planner_term_naming_a_perceived_object_is_a_check_error(tmp_path):
    raw = scene()
    raw["objectives"]["go"]["terms"].append(
        {"term": "distance", "a": "robot", "b": "box", "weight": 1.0}
    )
    _, path = load(tmp_path, raw)
    errors = [str(e) for e in planner_errors(path)]
    assert any("'box'" in e for e in errors), errors


def test_a_sensor_frame_the_world_lacks_is_a_check_error(tmp_path):
    sensors = [{"name": "lidar", "type": "lidar", "frame": "site:nowhere"}]
    _, path = load(tmp_path, scene(sensors=sensors))
    errors = [str(e) for e in world_errors(path)]
    assert any("sensors[0].frame" in e and "nowhere" in e for e in errors), errors


def test_the_layout_shows_the_sensors_and_leaves_the_perceived_objects_out(tmp_path):
    sc, _ = load(tmp_path, scene())
    layout = bridge_layout(sc)
    assert [m.body for m in layout.mocap] == ["cyl", "far", "goal"] and layout.perceived == ("box",)
    assert [(s.name, s.kind, s.shape, s.rate, s.frame) for s in layout.sensors] == [
        ("lidar", "lidar", (360,), 10.0, "robot"),
        ("cam", "depth", (48, 64), 10.0, "world"),
        ("down", "depth", (24, 32), 5.0, "world"),
    ]
    console = Console(record=True, width=200)
    print_layout(layout, console)
    text = console.export_text()
    assert "state.scans" in text and "[48, 64]" in text and "perceived objects" in text
    assert "sensors" in layout.to_dict()


# ---------------------------------------------------------------- faults


def faulty_scans(sc, seed: int = 0, steps: int = 0, **faults) -> list[Scan]:
    world = FaultyWorld(SimWorld(sc, seed), FaultConfig(**faults))
    out = world.scans()
    for _ in range(steps):
        world.step(np.zeros(2))
        out += world.scans()
    return out


def test_scan_noise_dropout_and_latency_apply_repeatably(tmp_path):
    sensors = [{"name": "lidar", "type": "lidar", "pos": [0, 0, 0.15], "rays": 4096}]
    sc, _ = load(tmp_path, scene(sensors=sensors))
    exact = faulty_scans(sc, drop_rate=0.5)[0]  # a fault of another kind: the scan untouched
    noisy = faulty_scans(sc, scan_noise_m=0.01)[0]
    hit = exact.hits()
    assert np.array_equal(noisy.hits(), hit)  # a return stays a return
    error = noisy.ranges[hit] - exact.ranges[hit]
    assert 0.008 < np.std(error) < 0.012 and abs(np.mean(error)) < 0.002
    assert np.all(noisy.ranges[~hit] == exact.ranges[~hit])
    holed = faulty_scans(sc, scan_dropout=0.3)[0]
    lost = hit & ~holed.hits()
    assert not (holed.hits() & ~hit).any() and 0.25 < lost.sum() / hit.sum() < 0.35
    assert np.array_equal(holed.ranges[holed.hits()], exact.ranges[holed.hits()])
    again = faulty_scans(sc, scan_noise_m=0.01)[0]
    other = faulty_scans(sc, seed=1, scan_noise_m=0.01)[0]
    assert np.array_equal(again.ranges, noisy.ranges)
    assert not np.array_equal(other.ranges, noisy.ranges)
    late = FaultyWorld(SimWorld(sc, 0), FaultConfig(scan_latency_ms=120.0))
    delivered = [[s.time for s in late.scans()]]
    for _ in range(6):
        late.step(np.zeros(2))
        delivered.append([round(s.time, 9) for s in late.scans()])
    # 120 ms is three steps of 50 ms: the reading of t = 0 comes at t = 0.15, stamped 0
    assert delivered == [[], [], [], [0.0], [], [0.1], []]


def test_the_lab_profile_reaches_the_states_readings(tmp_path):
    lab = PROFILES["lab"]
    assert (lab.scan_noise_m, lab.scan_dropout, lab.scan_latency_ms) == (0.01, 0.02, 50.0)
    assert PROFILES["nominal"].scan_noise_m == 0.0
    sc, _ = load(tmp_path, scene())
    episode = Episode(sc, 0, tmp_path / "log.jsonl", faults=lab)
    readings = []  # (world time at publishing, measurement time)
    try:
        for _ in range(8):
            state = episode.publish()
            if state is not None:
                readings += [(episode.world.time, scan.time) for scan in state.scans]
            episode.apply(np.zeros(2), -1)
    finally:
        episode.close()
    assert readings and all(t - measured >= 0.05 - 1e-9 for t, measured in readings)


# ---------------------------------------------------------------- the wire


def test_version_3_is_negotiated_and_a_version_2_planner_is_served_without_scans(tmp_path):
    sc, path = load(tmp_path, scene())
    port = free_port_block()
    server = start_server(str(path), port, tmp_path / "log.jsonl")
    ctx = zmq.Context()
    ends = Endpoints(port=port)

    def hello(versions) -> tuple[int, dict]:
        req = ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        req.connect(ends.control)
        req.send(P.encode(P.Hello(sc.name, sc.hash, versions=versions), 1))
        assert req.poll(30000)
        reply, version = P.decode_versioned(req.recv(), versions=P.VERSIONS)
        req.close()
        assert isinstance(reply, P.Welcome), reply
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.setsockopt(zmq.LINGER, 0)
        sub.connect(ends.state)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # re-published every 0.2 s in lock-step
            if sub.poll(1000):
                raw = msgpack.unpackb(sub.recv(), raw=False)
                if raw["v"] == version:
                    sub.close()
                    return version, raw
        raise AssertionError("no state of the chosen version")

    try:
        version, raw = hello([1, 2, 3])
        assert version == 3 and [s["name"] for s in raw["scans"]] == ["lidar", "cam", "down"]
        state = P.decode(msgpack.packb(raw, use_bin_type=True), expect="state", versions=(3,))
        assert state.mocap_pos.shape[0] == 3  # cyl, far, goal: the perceived box's row stays
        version, raw = hello([1, 2])
        assert version == 2 and "scans" not in raw
    finally:
        ctx.term()
        stop(server)


def test_a_world_without_sensors_publishes_no_scans(tmp_path):
    sc, _ = load(tmp_path, scene(sensors=[]))
    episode = Episode(sc, 0, tmp_path / "log.jsonl")
    try:
        frame = msgpack.unpackb(P.encode(episode.publish()), raw=False)
    finally:
        episode.close()
    assert "scans" not in frame and episode.world.sensors is None
