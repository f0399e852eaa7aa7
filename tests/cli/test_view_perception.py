"""What the browser view shows of the robot's sensors and the planner's map: the field frames the
planner sends a view (round trip, pooling, slicing, refusal of malformed ones), their records
for the replay, the planner making them only for a view, and the scene nodes of the scan points
and the heat map, live and replayed (viser's scene graph, no browser)."""

from __future__ import annotations

import json
import threading
import time
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest
import torch
import zmq
from hypothesis import given, settings
from hypothesis import strategies as st

from m3p2i.launch import free_port_block
from planner_client.perception.field import DistanceField
from planner_client.perception.field_message import (
    FIELD_TOPIC,
    HI,
    LO,
    MAX_SIDE,
    FieldPublisher,
    check_field_map,
    decode_field,
    encode_field,
    field_slice,
)
from server.inprocess import build_episode
from shared import protocol as P
from shared.endpoints import Endpoints, socket

STEP = (HI - LO) / 255  # m: one quantisation step


def _field(shape=(40, 60), res=0.05, origin=(-1.0, -2.0, 0.0), time=1.5) -> DistanceField:
    """A field whose distance grows along x from -0.5 m (an obstacle's inside) to 2.45 m."""
    values = np.broadcast_to(-0.5 + np.arange(shape[-1]) * res, shape).copy()
    return DistanceField(torch.tensor(values), origin[: len(shape)], res, time)


def test_a_2d_field_arrives_as_sent_to_a_quantisation_step():
    field = _field()
    fs = decode_field(encode_field(field))
    assert fs.q.shape == (40, 60) and fs.z is None and fs.time == 1.5
    assert fs.origin == (-1.0, -2.0) and fs.resolution == 0.05
    want = np.clip(field.values.numpy(), LO, HI)
    np.testing.assert_allclose(fs.distances, want, atol=STEP / 2 + 1e-6)


def test_a_large_field_is_min_pooled_so_a_thin_obstacle_still_shows():
    values = np.ones((450, 300))
    values[123, 77] = -0.2  # one cell of an obstacle
    fs = decode_field(encode_field(DistanceField(torch.tensor(values), (0.0, 0.0), 0.02)))
    stride = 3  # 450 cells into at most 200
    assert fs.q.shape == (150, 100) and max(fs.q.shape) <= MAX_SIDE
    assert fs.resolution == pytest.approx(0.02 * stride)
    # a pooled cell's centre is its 3 x 3 fine cells' middle one
    assert fs.origin == pytest.approx((0.02, 0.02))
    d = fs.distances
    assert d[123 // stride, 77 // stride] == pytest.approx(-0.2, abs=STEP)
    assert np.sum(d < 0) == 1


def test_a_3d_field_is_drawn_as_its_slice_a_few_cm_above_its_bottom():
    values = np.stack([np.full((20, 30), 0.1 * k) for k in range(8)])  # [D, H, W]
    field = DistanceField(torch.tensor(values), (0.0, 0.0, 0.8), 0.02)
    fs = decode_field(encode_field(field))
    # the bottom face at 0.79 m; 5 cm above it is the layer centred at 0.84 m (k = 2)
    assert fs.z == pytest.approx(0.84)
    np.testing.assert_allclose(fs.distances, 0.2, atol=STEP)


def _frame_map(**change) -> dict:
    good = msgpack.unpackb(encode_field(_field())[len(FIELD_TOPIC) :], raw=False)
    for key, value in change.items():
        if value is None:
            del good[key]
        else:
            good[key] = value
    return good


def _frame(obj) -> bytes:
    return FIELD_TOPIC + msgpack.packb(obj, use_bin_type=True)


def _cells(shape, dtype="|u1", nbytes=None) -> dict:
    n = int(np.prod(shape)) * np.dtype(dtype).itemsize if nbytes is None else nbytes
    return {"nd": True, "dtype": dtype, "shape": list(shape), "data": bytes(n)}


@pytest.mark.parametrize(
    "frame, reason",
    [
        (b"\x8a" + bytes(20), "does not start with the field topic"),
        (FIELD_TOPIC + b"\xc1garbage", "not a msgpack map"),
        (FIELD_TOPIC + bytes(MAX_SIDE * MAX_SIDE + 2000), "over the limit"),
        (_frame([1, 2]), "expected a map"),
        (_frame(_frame_map(lo=None)), "keys"),
        (_frame(_frame_map(colour=1)), "keys"),
        (_frame(_frame_map(v=2)), "this side reads 1"),
        (_frame(_frame_map(values=_cells((40, 60), nbytes=100))), "needs 2400"),
        (_frame(_frame_map(values=_cells((40, 60), "<f4"))), "uint8"),
        (_frame(_frame_map(values=_cells((2, 40, 60)))), "uint8"),
        (_frame(_frame_map(values=_cells((0, 60)))), "uint8"),
        (_frame(_frame_map(values=_cells((201, 60)))), "over 200 a side"),
        (_frame(_frame_map(origin=[float("nan"), 0.0])), "field.origin"),
        (_frame(_frame_map(origin=[0.0])), "expected \\[x, y\\]"),
        (_frame(_frame_map(resolution=float("inf"))), "field.resolution"),
        (_frame(_frame_map(resolution=0.0)), "must be > 0"),
        (_frame(_frame_map(lo=2.0)), "lo 2.0 < hi"),
        (_frame(_frame_map(time=-1.0)), "field.time"),
        (_frame(_frame_map(z=float("nan"))), "field.z"),
        (_frame(_frame_map(hi="far")), "expected a number"),
    ],
    ids=lambda v: v if isinstance(v, str) else None,
)
def test_a_malformed_field_frame_is_refused_with_the_reason(frame, reason):
    with pytest.raises(P.ProtocolError, match=reason):
        decode_field(frame)


_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.binary(max_size=64),
    st.lists(st.floats(allow_nan=True), max_size=3),
    st.fixed_dictionaries(
        {
            "nd": st.just(True),
            "dtype": st.sampled_from(["|u1", "<f8", "<i4"]),
            "shape": st.lists(st.integers(-2, 300), max_size=3),
            "data": st.binary(max_size=512),
        }
    ),
)


@settings(max_examples=400, deadline=None, derandomize=True, database=None)
@given(
    key=st.sampled_from(["v", "time", "origin", "resolution", "lo", "hi", "values", "z", "x"]),
    value=_VALUES,
)
def test_a_field_frame_with_any_value_anywhere_is_read_checked_or_refused(key, value):
    frame = _frame(_frame_map(**{key: value}) if value is not None else _frame_map())
    try:
        fs = decode_field(frame)
    except P.ProtocolError:
        return
    assert fs.q.dtype == np.uint8 and fs.q.ndim == 2 and max(fs.q.shape) <= MAX_SIDE
    assert np.isfinite([*fs.origin, fs.resolution, fs.lo, fs.hi, fs.time]).all()
    assert fs.resolution > 0 and fs.lo < fs.hi


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(data=st.binary(max_size=256))
def test_a_field_frame_of_any_bytes_is_refused_with_a_reason(data):
    with pytest.raises(P.ProtocolError):
        decode_field(FIELD_TOPIC + data)


def test_a_diagnostics_reader_skips_field_frames():
    with pytest.raises(P.ProtocolError, match="not a msgpack message"):
        P.decode(encode_field(_field()), expect="diagnostics")


def test_field_records_round_trip_and_corrupt_ones_are_refused():
    from m3p2i.view.perception import field_from_record, field_record

    fs = field_slice(_field())
    rec = json.loads(json.dumps(field_record(fs)))
    assert rec["kind"] == "field" and len(rec["values"]) < 2000  # compressed: a ramp
    back = field_from_record(rec)
    np.testing.assert_array_equal(back.q, fs.q)
    assert (back.origin, back.resolution, back.time, back.z) == (fs.origin, 0.05, 1.5, None)
    with pytest.raises(P.ProtocolError, match="not zlib"):
        field_from_record(rec | {"values": "!!"})
    with pytest.raises(P.ProtocolError, match="needs"):
        field_from_record(rec | {"shape": [41, 60]})
    with pytest.raises(P.ProtocolError, match="field\\.origin"):
        field_from_record(rec | {"origin": [1e9, 0]})
    with pytest.raises(P.ProtocolError, match="keys"):
        check_field_map({"v": 1})


def test_the_planner_sends_a_field_when_it_is_new_at_most_twice_a_second():
    now = [0.0]
    pub = FieldPublisher(clock=lambda: now[0])
    a, b = _field(), _field(time=2.0)
    assert pub.frame(None) is None
    assert decode_field(pub.frame(a)).time == 1.5
    now[0] = 5.0
    assert pub.frame(a) is None  # sent already
    assert pub.frame(b) is not None
    now[0] = 5.3
    assert pub.frame(_field(time=3.0)) is None  # too soon


class _Controller:
    """What PlannerClient reads of a controller after a step, counting the map's reads."""

    def __init__(self):
        self.reads = 0
        self.map = SimpleNamespace(latest=self._latest)

    def _latest(self):
        self.reads += 1
        return _field(time=float(self.reads))

    def step(self, state):
        return P.Command(session=state.session, seq=state.seq, ctrl=np.zeros(2))

    def diagnostics(self):
        return P.Diagnostics(
            seq=1,
            action="go",
            alternatives=["go"],
            mode_names=["go"],
            mode_weights=np.ones(1),
            top=np.zeros((1, 2, 3)),
            plan_time=0.01,
        )

    def close(self):
        pass


def _received(sub: zmq.Socket, seconds: float = 0.5) -> list[bytes]:
    got, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        if sub.poll(50):
            got.append(sub.recv())
    return got


def test_the_planner_makes_fields_only_while_a_view_subscribes_to_them():
    from planner_client.loop import PlannerClient

    port = free_port_block()
    controller = _Controller()
    client = PlannerClient(controller, Endpoints(port=port), "navigation_seen", "hash")
    ctx = zmq.Context()
    recorder = socket(ctx, zmq.SUB)  # a diagnostics recorder: everything, no field asked
    recorder.setsockopt(zmq.SUBSCRIBE, b"")
    recorder.connect(Endpoints(port=port).diagnostics)
    state = P.State("s", 1, 0.0, *(np.zeros(0) for _ in range(3)), np.zeros(0), np.zeros(0))
    try:
        end = time.monotonic() + 10
        while not recorder.poll(0) and time.monotonic() < end:
            client._step(state)  # until the recorder's subscription is in place
            time.sleep(0.02)
        for _ in range(5):
            client._step(state)
        assert controller.reads == 0  # diagnostics, but no view: not a field made
        frames = _received(recorder)
        assert frames and all(not f.startswith(FIELD_TOPIC) for f in frames)
        view = socket(ctx, zmq.SUB)
        view.setsockopt(zmq.SUBSCRIBE, FIELD_TOPIC)
        view.connect(Endpoints(port=port).diagnostics)
        end = time.monotonic() + 10
        while controller.reads == 0 and time.monotonic() < end:
            client._step(state)
            time.sleep(0.02)
        frames = _received(view)
        assert frames and decode_field(frames[0]).q.shape == (40, 60)
        view.close(0)
        end = time.monotonic() + 10
        while time.monotonic() < end:  # until the unsubscription reaches the planner
            reads = controller.reads
            for _ in range(5):
                client._step(state)
                time.sleep(0.02)
            if controller.reads == reads:
                break
        assert controller.reads == reads  # the view left: no more fields
    finally:
        recorder.close(0)
        ctx.term()
        client.close()


# ------------------------------------------------------------------------------ the page


@pytest.fixture
def seen(tmp_path):
    """navigation_seen's first state (the lidar reads at the start) and the log of a
    two-step episode from it, in ``tmp_path/run``."""
    episode = build_episode("navigation_seen", seed=0, log_path=tmp_path / "run" / "e.jsonl")
    try:
        state = episode.publish()
        assert state.scans, "the lidar reads at the start"
        for _ in range(2):
            cmd = P.Command(session=state.session, seq=state.seq, ctrl=np.zeros(2))
            episode.play(cmd)
            episode.publish()
    finally:
        episode.close()
    return state, tmp_path / "run" / "e.jsonl"


def _nodes(server) -> set[str]:
    return set(server.scene._handle_from_node_name)


def test_the_live_page_draws_the_scans_and_the_field_and_records_them(seen):
    pytest.importorskip("viser")
    from m3p2i.view import LiveView, load_replay
    from m3p2i.view.playback import ReplayView
    from shared.scenario import load_scenario

    state, log = seen
    ends = Endpoints(port=free_port_block())
    ctx = zmq.Context()
    world, planner = socket(ctx, zmq.PUB), socket(ctx, zmq.XPUB)
    world.bind(ends.state)
    planner.bind(ends.diagnostics)
    record = log.parent / "diagnostics.jsonl"
    scenario = load_scenario("navigation_seen")
    view = LiveView(scenario, ends, "127.0.0.1", free_port_block(count=1), record)
    serving = threading.Thread(target=view.serve, daemon=True)
    serving.start()
    layers = {"/perception/scans/lidar", "/perception/field"}
    try:
        end = time.monotonic() + 20
        while time.monotonic() < end and not layers <= _nodes(view.server):
            world.send(P.encode(state))
            planner.send(encode_field(_field(shape=(100, 100), origin=(-2.5, -2.5), time=0.0)))
            time.sleep(0.1)
        view.stop.set()
        serving.join(10)
        assert layers <= _nodes(view.server), sorted(_nodes(view.server))
        cloud = view.server.scene._handle_from_node_name["/perception/scans/lidar"]
        # one point per ray that returned, none for the others
        assert len(cloud.points) == int(state.scans[0].hits().sum()) > 100
        view.perception.show("field", False)
        assert not view.server.scene._handle_from_node_name["/perception/field"].visible
        assert cloud.visible
    finally:
        view.stop.set()
        serving.join(10)
        view.close()
        world.close(0)
        planner.close(0)
        ctx.term()
    kinds = [json.loads(line).get("kind") for line in record.open()]
    assert "scan" in kinds and "field" in kinds
    # the replay of the episode's log draws them again, from the records beside it
    replay = load_replay(log)
    assert replay.perception.field_at(0.0) is not None
    page = ReplayView(replay, "127.0.0.1", free_port_block(count=1))
    try:
        assert layers <= _nodes(page.server), sorted(_nodes(page.server))
    finally:
        page.close()


def test_the_heat_map_is_red_at_obstacles_blue_at_the_fade_and_clear_beyond():
    from m3p2i.view.perception import heat_rgba

    rgba = heat_rgba(np.array([[-0.1, 0.0, 0.5, 1.0, 1.6]]), fade=1.0)[0].astype(int)
    inside, surface, middle, fade, far = rgba
    assert inside[0] > 100 and inside[1] < 20 and inside[3] > 200  # dark red, nearly opaque
    assert surface[0] > 200 and surface[1] < 50 and surface[3] == 200
    assert middle[0] > middle[2] and middle[3] == 150
    assert fade[2] > 200 and fade[0] < 60 and fade[3] == 100  # blue, half as opaque
    assert far[3] == 0
