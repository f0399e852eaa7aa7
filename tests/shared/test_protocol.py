"""Wire protocol: round trips, and every kind of bad message is refused with a reason."""

import msgpack
import numpy as np
import pytest

from shared import protocol as P

V = P.PROTOCOL_VERSION


def _state(**kw):
    base = dict(
        session="abcd",
        seq=3,
        time=0.15,
        qpos=np.arange(4.0),
        qvel=np.zeros(4),
        act=np.zeros(0),
        mocap_pos=np.zeros((0, 3)),
        mocap_quat=np.zeros((0, 4)),
        extras={"battery": 87.5},
    )
    base.update(kw)
    return P.State(**base)


def test_state_round_trip_keeps_arrays_and_fields():
    msg = _state()
    back = P.decode(P.encode(msg))
    assert isinstance(back, P.State)
    assert back.seq == 3 and back.session == "abcd" and back.extras == {"battery": 87.5}
    np.testing.assert_array_equal(back.qpos, msg.qpos)
    assert back.mocap_pos.shape == (0, 3)
    assert back.status == "running"


@pytest.mark.parametrize(
    "msg",
    [
        P.Hello(scenario="nav", scenario_hash="00ff"),
        P.Welcome(
            scenario="nav", scenario_hash="00ff", mode="lockstep", dt=0.05, nu=2, session="s"
        ),
        P.Command(session="s", seq=7, ctrl=np.array([0.5, -0.5]), plan_time=0.02, action="move"),
        P.Command(
            session="s",
            seq=7,
            ctrl=np.array([0.5, -0.5]),
            plan_ctrl=np.ones((12, 2)),
            plan_t0=1.25,
            plan_dt=0.03,
        ),
        P.Diagnostics(
            seq=1,
            action="push",
            alternatives=["push", "pull"],
            mode_names=["push", "pull"],
            mode_weights=np.array([0.7, 0.3]),
            top=np.zeros((5, 15, 3)),
            plan_time=0.01,
            lead=0.03,
            steps=3,
        ),
        P.Error(reason="nope"),
        P.Control(op="reset"),
    ],
)
def test_every_message_type_round_trips(msg):
    back = P.decode(P.encode(msg))
    assert type(back) is type(msg)
    for name in P._SCHEMA[msg.type]:
        a, b = getattr(msg, name), getattr(back, name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b


def _raw(**fields):
    return msgpack.packb(fields, use_bin_type=True)


def _arr(a):
    return P.encode_array(np.asarray(a, dtype=float))


@pytest.mark.parametrize(
    "frame, reason",
    [
        (b"\xc1\xff\x00garbage", "not a msgpack message"),
        (msgpack.packb([1, 2, 3]), "must be a map"),
        (_raw(type="teleport", v=V), "unknown message type"),
        (_raw(type="state", v=99, reason="x"), "protocol version 99 not supported"),
        (
            _raw(type="hello", v=1, scenario="a", scenario_hash="h"),
            "protocol version 1 not supported",
        ),
        (_raw(type="error", reason="x"), "protocol version None"),
        (_raw(type="command", v=V, session="s", seq=1), "missing field 'ctrl'"),
        (_raw(type="command", v=V, session="s", seq="1", ctrl=_arr([0, 0])), "expected an integer"),
        (_raw(type="command", v=V, session="s", seq=1, ctrl=[0.0, 0.0]), "expected an array map"),
        (_raw(type="command", v=V, session="s", seq=1, ctrl=_arr([[0, 0]])), "expected shape [nu]"),
        (_raw(type="command", v=V, session="s", seq=1, ctrl=_arr([np.nan, 0])), "NaN or inf"),
        (_raw(type="command", v=V, session="s", seq=1, ctrl=_arr([0, 0]), evil=1), "unknown field"),
        (
            _raw(
                type="command",
                v=V,
                session="s",
                seq=1,
                ctrl={"nd": True, "dtype": "<f8", "shape": [3], "data": b"\x00" * 8},
            ),
            "needs 24",
        ),
        (
            _raw(
                type="command",
                v=V,
                session="s",
                seq=1,
                ctrl={"nd": True, "dtype": "|O", "shape": [1], "data": b"\x00" * 8},
            ),
            "unsupported dtype",
        ),
        (_raw(type="command", v=V, session="s", seq=-4, ctrl=_arr([0, 0])), "seq must be >= 0"),
        (_raw(type="control", v=V, op="rm -rf"), "control.op"),
        (
            _raw(
                type="command", v=V, session="s", seq=1, ctrl=_arr([0, 0]), plan_ctrl=_arr([[0, 0]])
            ),
            "plan_ctrl, plan_t0 and plan_dt together",
        ),
        (
            _raw(
                type="command",
                v=V,
                session="s",
                seq=1,
                ctrl=_arr([0, 0]),
                plan_ctrl=_arr([[0, 0, 0]]),
                plan_t0=0.0,
                plan_dt=0.01,
            ),
            "expected shape [H >= 1, 2]",
        ),
        (
            _raw(
                type="command",
                v=V,
                session="s",
                seq=1,
                ctrl=_arr([0, 0]),
                plan_ctrl=_arr([[0, 0]]),
                plan_t0=0.0,
                plan_dt=0.0,
            ),
            "plan_dt must be > 0",
        ),
        (
            _raw(
                type="state",
                v=V,
                session="s",
                seq=1,
                time=0.0,
                qpos=_arr([0]),
                qvel=_arr([0]),
                act=_arr([]),
                mocap_pos=_arr([]),
                mocap_quat=_arr([]),
                lag=-0.1,
            ),
            "state.lag: -0.1 s (expected world seconds in [0, 1e9])",
        ),
    ],
)
def test_malformed_messages_are_refused_with_a_reason(frame, reason):
    with pytest.raises(P.ProtocolError, match=None) as info:
        P.decode(frame)
    assert reason in str(info.value)


def test_oversize_message_is_refused_before_decoding():
    with pytest.raises(P.ProtocolError, match="over the limit"):
        P.decode(b"\x00" * (P.MAX_MESSAGE_BYTES + 1))


def test_oversize_array_is_refused():
    big = {"nd": True, "dtype": "<f8", "shape": [10**7], "data": b""}
    with pytest.raises(P.ProtocolError, match="over the limit"):
        P.decode(_raw(type="command", v=V, session="s", seq=1, ctrl=big))


def test_unexpected_type_on_a_socket_is_refused():
    with pytest.raises(P.ProtocolError, match="unexpected message type 'error'"):
        P.decode(P.encode(P.Error(reason="x")), expect="command")


def test_no_pickle_extension_types_are_accepted():
    # msgpack ext types (what some libraries use for custom objects) are not part of the protocol
    frame = msgpack.packb({"type": "error", "v": 1, "reason": msgpack.ExtType(1, b"\x80\x04")})
    with pytest.raises(P.ProtocolError):
        P.decode(frame)


def test_a_refusal_from_a_peer_of_another_version_is_read_with_its_reason():
    # an old or newer peer must learn why it was refused, not only that the version differs
    back = P.decode(_raw(type="error", v=1, reason="refused: protocol version 2 not supported"))
    assert isinstance(back, P.Error) and "version 2" in back.reason


def test_a_command_without_a_plan_is_still_a_command():
    back = P.decode(P.encode(P.Command(session="s", seq=1, ctrl=np.zeros(2))))
    assert not back.has_plan and back.plan_t0 is None


@pytest.mark.parametrize("kind", [{"a": 1}, [1], 1.5, None, b"state"])
def test_a_type_that_is_not_a_string_is_refused(kind):
    # found by tests/shared/test_fuzz.py: an unhashable type (a map, a list) raised TypeError
    with pytest.raises(P.ProtocolError, match="unknown message type"):
        P.decode(msgpack.packb({"type": kind, "v": V}, use_bin_type=True))


@pytest.mark.parametrize(
    "array, reason",
    [
        ({"nd": True, "dtype": {"a": 1}, "shape": [1], "data": b"\x00" * 8}, "unsupported dtype"),
        ({"nd": True, "dtype": ["<f8"], "shape": [1], "data": b"\x00" * 8}, "unsupported dtype"),
        # np.prod wraps around in int64: 2**63 · 2 "is" 0 elements, and b"" matched it
        ({"nd": True, "dtype": "<f8", "shape": [2**63, 2], "data": b""}, "over the limit"),
        ({"nd": True, "dtype": "<f8", "shape": [2**64 - 1], "data": b""}, "over the limit"),
        ({"nd": True, "dtype": "<f8", "shape": [2**32, 2**32, 0], "data": b""}, "over the limit"),
    ],
)
def test_arrays_with_unhashable_dtypes_or_overflowing_shapes_are_refused(array, reason):
    # found by tests/shared/test_fuzz.py: TypeError, and ValueError from numpy's reshape
    with pytest.raises(P.ProtocolError) as info:
        P.decode(_raw(type="command", v=V, session="s", seq=1, ctrl=array))
    assert reason in str(info.value)


def _state_raw(**kw):
    base = dict(
        type="state",
        v=V,
        session="s",
        seq=1,
        time=0.0,
        qpos=_arr([0, 0]),
        qvel=_arr([0, 0]),
        act=_arr([]),
        mocap_pos=_arr(np.zeros((1, 3))),
        mocap_quat=_arr(np.ones((1, 4))),
    )
    return _raw(**{**base, **kw})


def _diag_raw(**kw):
    base = dict(
        type="diagnostics",
        v=V,
        seq=1,
        action="a",
        alternatives=[],
        mode_names=["m"],
        mode_weights=_arr([1.0]),
        top=_arr(np.zeros((1, 4, 3))),
        plan_time=0.0,
    )
    return _raw(**{**base, **kw})


@pytest.mark.parametrize(
    "frame, reason",
    [
        (_state_raw(qpos=_arr(np.zeros((0, 0)))), "state.qpos: expected shape [n]"),
        (_state_raw(qvel=_arr(np.zeros((2, 1)))), "state.qvel: expected shape [n]"),
        (
            _state_raw(mocap_pos=_arr(np.zeros((1, 2)))),
            "state.mocap_pos: expected shape [nmocap, 3]",
        ),
        (_state_raw(mocap_quat=_arr(np.ones((2, 4)))), "state.mocap_quat: expected shape [1, 4]"),
        (
            _diag_raw(mode_weights=_arr(np.zeros((1, 1)))),
            "diagnostics.mode_weights: expected shape",
        ),
        (_diag_raw(top=_arr(np.zeros((1, 4)))), "diagnostics.top: expected shape [M, T, 3]"),
        (_diag_raw(top=_arr(np.zeros((1, 4, 2)))), "diagnostics.top: expected shape [M, T, 3]"),
    ],
)
def test_arrays_of_other_shapes_than_documented_are_refused(frame, reason):
    # found by tests/shared/test_fuzz.py: a 2-d mode_weights reached the view
    # (float(row): TypeError)
    with pytest.raises(P.ProtocolError) as info:
        P.decode(frame)
    assert reason in str(info.value)


def test_a_state_without_mocap_bodies_may_send_empty_arrays():
    back = P.decode(_state_raw(mocap_pos=_arr([]), mocap_quat=_arr([])))
    assert back.mocap_pos.size == back.mocap_quat.size == 0


def _welcome_raw(**kw):
    base = dict(
        type="welcome",
        v=V,
        scenario="a",
        scenario_hash="h",
        mode="realtime",
        dt=0.05,
        nu=2,
        session="s",
    )
    return _raw(**{**base, **kw})


@pytest.mark.parametrize(
    "frame, reason",
    [
        (_welcome_raw(dt=-1e308), "welcome.dt"),
        (_welcome_raw(dt=-0.0), "welcome.dt"),
        (_welcome_raw(dt=5e-324), "welcome.dt"),
        (_welcome_raw(nu=-3), "welcome.nu"),
        (_welcome_raw(seed=-1), "welcome.seed"),
        (_welcome_raw(seed=2**40), "welcome.seed"),
    ],
)
def test_a_welcome_with_an_impossible_world_is_refused(frame, reason):
    # found by tests/shared/test_fuzz.py: dt -1e308 was accepted (the planner divides by it, and a
    # negative seed makes numpy's default_rng raise)
    with pytest.raises(P.ProtocolError) as info:
        P.decode(frame)
    assert reason in str(info.value)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_a_state_extra_that_is_not_a_finite_number_is_refused(value):
    # found by tests/shared/test_fuzz.py: extras {'battery': nan} were accepted
    with pytest.raises(P.ProtocolError, match=r"state\.extras"):
        P.decode(_state_raw(extras={"battery": value}))
