"""Bad input never crashes anything: property-based fuzzing (Hypothesis) of what comes from
outside a process.

- Every message type's decoder (:func:`shared.protocol.decode` with ``expect`` each type), on raw
  bytes, on arbitrary msgpack values, and on valid messages with fields (and array maps' keys)
  replaced by hostile values: NaN, ±inf, 1e308, 5e-324, -0.0, arrays announcing more elements
  than they carry, wrong dtypes and types, unicode, deep nesting. Only ``ProtocolError`` may
  escape, and a decoded message's numbers are finite and its arrays of the documented shapes.
- The scenario loader on shipped scenarios with one value replaced by such a value: it loads,
  or raises ``ConfigError`` naming the file and the key; never anything else.

Derandomized (the same examples every run, no example database) and sized to run in about a
minute on one core.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared import protocol as P
from shared.config import ConfigError, ConfigErrors
from shared.scenario import SCENARIO_DIR, load_scenario

V = P.PROTOCOL_VERSION
TYPES = sorted(P.MESSAGES)
FUZZ = settings(
    max_examples=600,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)
FUZZ_MORE = settings(FUZZ, max_examples=3000)

HOSTILE_FLOATS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -5e-324, -0.0]


# ---------------------------------------------------------------- hostile values


def _nested(depth: int, leaf=0):
    out = leaf
    for i in range(depth):
        out = [out] if i % 2 else {"k": out}
    return out


def _array_map(dtype, shape, data) -> dict:
    return {"nd": True, "dtype": dtype, "shape": shape, "data": data}


_dims = st.one_of(st.integers(0, 8), st.sampled_from([2**31, 2**32 + 1, 2**62, 2**63, 2**64 - 1]))
array_maps = st.builds(
    _array_map,
    dtype=st.sampled_from(["<f8", "<f4", "<i4", "<i8", "|u1", "|b1", ">f8", "|O", "<c16", "", 5]),
    shape=st.one_of(
        st.lists(_dims, max_size=6), st.just([-1]), st.just([1.5]), st.just("3"), st.just([True])
    ),
    data=st.one_of(st.binary(max_size=80), st.just("text"), st.none()),
)
hostile_arrays = st.builds(
    lambda v, shape: P.encode_array(np.full(shape, v)),
    st.sampled_from(HOSTILE_FLOATS + [0.0, 1.0]),
    st.sampled_from([(), (1,), (3,), (4,), (2, 3), (1, 2, 3), (2, 2, 2, 2), (0,), (0, 3)]),
)
hostile_scalars = st.one_of(
    st.sampled_from(HOSTILE_FLOATS),
    st.floats(),
    st.integers(-(2**63), 2**64 - 1),
    st.booleans(),
    st.none(),
    st.text(max_size=20),
    st.binary(max_size=20),
    st.sampled_from(["\u202e\u0000", "é" * 5000, "running\x00", "lockstep ", "\ud7ff🤖"]),
)
msgpackable = st.recursive(
    hostile_scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
hostile = st.one_of(
    st.sampled_from(HOSTILE_FLOATS + [0, -1, 0.0, -(2**63)]),
    hostile_scalars,
    array_maps,
    hostile_arrays,
    msgpackable,
    st.integers(50, 600).map(_nested),
)


# ---------------------------------------------------------------- valid messages


def _valid() -> dict[str, dict]:
    msgs = [
        P.Hello(scenario="navigation", scenario_hash="abc"),
        P.Welcome(
            scenario="navigation",
            scenario_hash="abc",
            mode="realtime",
            dt=0.05,
            nu=2,
            session="s1",
            seed=3,
        ),
        P.State(
            session="s1",
            seq=4,
            time=0.2,
            qpos=np.arange(4.0),
            qvel=np.zeros(4),
            act=np.zeros(0),
            mocap_pos=np.zeros((2, 3)),
            mocap_quat=np.ones((2, 4)),
            extras={"battery": 80.0},
            lag=0.01,
        ),
        P.Command(
            session="s1",
            seq=4,
            ctrl=np.zeros(2),
            plan_time=0.01,
            action="go",
            plan_ctrl=np.zeros((5, 2)),
            plan_t0=0.25,
            plan_dt=0.05,
        ),
        P.Diagnostics(
            seq=4,
            action="go",
            alternatives=["a", "b"],
            mode_names=["m0", "m1"],
            mode_weights=np.array([0.3, 0.7]),
            top=np.zeros((2, 5, 3)),
            plan_time=0.02,
            lead=0.05,
            steps=1,
            top_modes=np.array([0, 1]),
        ),
        P.Error(reason="no"),
        P.Control(
            op="move",
            object="cube_a",
            pos=np.array([0.1, 0.2, 1.0]),
            quat=np.array([1.0, 0.0, 0.0, 0.0]),
        ),
    ]
    return {m.type: msgpack.unpackb(P.encode(m), raw=False) for m in msgs}


VALID = _valid()


def _finite(x) -> bool:
    return bool(np.all(np.isfinite(x)))


def assert_well_formed(msg) -> None:
    """What every consumer of a decoded message may rely on."""
    schema = P._SCHEMA[msg.type]
    for name, (kind, _) in schema.items():
        value = getattr(msg, name)
        if value is None:
            continue
        if kind == "float":
            assert isinstance(value, float) and math.isfinite(value), (name, value)
        elif kind == "int":
            assert isinstance(value, int) and not isinstance(value, bool), (name, value)
        elif kind == "str":
            assert isinstance(value, str), (name, value)
        elif kind == "floatmap":
            assert all(isinstance(v, float) and math.isfinite(v) for v in value.values()), value
        elif kind == "array":
            assert isinstance(value, np.ndarray) and value.ndim <= 4, (name, value)
            if value.dtype.kind == "f":
                assert _finite(value), (name, value)
    if isinstance(msg, P.State):
        assert msg.qpos.ndim == msg.qvel.ndim == msg.act.ndim == 1
        n = msg.mocap_pos.size // 3
        assert msg.mocap_pos.size == 3 * n and msg.mocap_quat.size == 4 * n
    if isinstance(msg, P.Command):
        assert msg.ctrl.ndim == 1
        if msg.has_plan:
            assert msg.plan_ctrl.shape[1:] == msg.ctrl.shape and msg.plan_ctrl.shape[0] >= 1
            assert msg.plan_dt >= P.MIN_PLAN_DT
            assert math.isfinite(msg.plan_t0 + msg.plan_ctrl.shape[0] * msg.plan_dt)
    if isinstance(msg, P.Diagnostics):
        assert msg.top.ndim == 3 and msg.top.shape[2] == 3, msg.top.shape
        assert msg.mode_weights.ndim == 1
        if msg.top_modes is not None:
            assert msg.top_modes.shape == msg.top.shape[:1]
    if isinstance(msg, P.Welcome):
        assert msg.dt > 0 and msg.nu >= 0
    if isinstance(msg, P.Control) and msg.op == "move":
        assert msg.pos.shape == (3,) and (msg.quat is None or msg.quat.shape == (4,))


def decode_or_refuse(frame: bytes, expect) -> None:
    try:
        msg = P.decode(frame, expect=expect)
    except P.ProtocolError:
        return
    assert_well_formed(msg)


def _pack(obj) -> bytes | None:
    try:
        return msgpack.packb(obj, use_bin_type=True)
    except (ValueError, OverflowError, TypeError):  # not msgpack-able (too deep, too big)
        return None


# ---------------------------------------------------------------- the decoder


def test_the_valid_messages_decode():
    for kind, raw in VALID.items():
        assert_well_formed(P.decode(_pack(raw), expect=kind))


@FUZZ
@given(frame=st.binary(max_size=200), expect=st.sampled_from(TYPES + [None]))
def test_raw_bytes_are_decoded_or_refused(frame, expect):
    decode_or_refuse(frame, expect)


@FUZZ
@given(
    kind=st.sampled_from(TYPES),
    fields=st.dictionaries(st.text(max_size=12), hostile, max_size=6),
    version=st.sampled_from([V, V, 1, None, "2", 2.0]),
)
def test_arbitrary_values_under_each_type_are_decoded_or_refused(kind, fields, version):
    frame = _pack({**fields, "type": kind, "v": version})
    if frame is not None:
        decode_or_refuse(frame, kind)


@st.composite
def mutated(draw):
    """A valid message of each type with one to three of its values replaced."""
    kind = draw(st.sampled_from(TYPES))
    raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in VALID[kind].items()}
    names = sorted(set(P._SCHEMA[kind]) | {"type", "v"})
    for _ in range(draw(st.integers(1, 3))):
        name = draw(st.sampled_from(names))
        if isinstance(raw.get(name), dict) and draw(st.booleans()):
            inner = raw[name]  # inside an array map, or a map of numbers
            keys = ["dtype", "shape", "data", "nd"] if inner.get("nd") else sorted(inner) + ["x"]
            inner[draw(st.sampled_from(keys))] = draw(hostile)
        elif draw(st.integers(0, 9)) == 0:
            raw.pop(name, None)
        else:
            raw[name] = draw(hostile)
    return kind, raw


@FUZZ_MORE
@given(case=mutated(), strict=st.booleans())
def test_valid_messages_with_hostile_fields_are_decoded_or_refused(case, strict):
    kind, raw = case
    frame = _pack(raw)
    if frame is not None:
        decode_or_refuse(frame, kind if strict else None)


SWEEP_VALUES = [
    *HOSTILE_FLOATS,
    0,
    -1,
    2**63,
    2**64 - 1,
    -(2**63),
    True,
    None,
    "",
    "\u202e🤖",
    b"\x00",
    [],
    {},
    [math.nan],
    {"k": math.nan},
    _nested(300),
    P.encode_array(np.array([math.nan])),
    P.encode_array(np.zeros((2, 2, 2))),
]


def _sweep_cases():
    """Every field of every valid message (and every key of its maps) × every value above."""
    for kind, raw in VALID.items():
        for name, value in raw.items():
            keys = [()] + ([(k,) for k in value] + [("extra",)] if isinstance(value, dict) else [])
            for key in keys:
                yield kind, (name, *key)


@pytest.mark.parametrize(
    "kind, path",
    list(_sweep_cases()),
    ids=lambda p: ".".join(map(str, p)) if isinstance(p, tuple) else p,
)
def test_every_field_with_every_hostile_value_is_decoded_or_refused(kind, path):
    for value in SWEEP_VALUES:
        raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in VALID[kind].items()}
        node = raw
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
        frame = _pack(raw)
        if frame is not None:
            decode_or_refuse(frame, kind)


@FUZZ
@given(
    kind=st.sampled_from(["state", "command", "diagnostics", "control"]),
    dims=st.lists(
        st.sampled_from([0, 1, 3, 2**31, 2**32, 2**62, 2**63, 2**64 - 1]), min_size=1, max_size=4
    ),
    dtype=st.sampled_from(["<f8", "<f4", "<i4", "|u1", "|b1"]),
    data=st.binary(max_size=64),
)
def test_arrays_announcing_more_than_they_carry_are_refused(kind, dims, dtype, data):
    raw = dict(VALID[kind])
    name = next(n for n, (k, _) in P._SCHEMA[kind].items() if k == "array" and n in raw)
    raw[name] = _array_map(dtype, dims, data)
    decode_or_refuse(_pack(raw), kind)


# ---------------------------------------------------------------- the scenario loader

FUZZED_SCENARIOS = ("navigation", "pick_place")
SOURCES = {
    name: yaml.safe_load((SCENARIO_DIR / f"{name}.yaml").read_text()) for name in FUZZED_SCENARIOS
}


def _paths(node, prefix=()) -> list[tuple]:
    out = []
    items = (
        node.items()
        if isinstance(node, dict)
        else enumerate(node)
        if isinstance(node, list)
        else ()
    )
    for k, v in items:
        out.append(prefix + (k,))
        out.extend(_paths(v, prefix + (k,)))
    return out


PATHS = {name: _paths(raw) for name, raw in SOURCES.items()}

yaml_hostile = st.one_of(
    st.sampled_from(HOSTILE_FLOATS),
    st.sampled_from([10**400, -(10**400), 2**63, -1, 0]),
    st.booleans(),
    st.none(),
    st.text(max_size=20),
    st.sampled_from(["\u202e", "é" * 3000, "", "~", ".inf", "null"]),
    st.lists(st.sampled_from(HOSTILE_FLOATS + [1.0, "x", None]), max_size=7),
    st.dictionaries(st.text(max_size=6), st.sampled_from(HOSTILE_FLOATS + [1, "x"]), max_size=3),
    st.integers(20, 200).map(_nested),
)


def _replace(raw, path, value):
    node = raw
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


def _copy(obj):
    if isinstance(obj, dict):
        return {k: _copy(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_copy(v) for v in obj]
    return obj


@settings(
    max_examples=300,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)
@given(name=st.sampled_from(FUZZED_SCENARIOS), data=st.data())
def test_a_scenario_with_a_hostile_value_loads_or_names_file_and_key(tmp_path_factory, name, data):
    raw = _copy(SOURCES[name])
    for _ in range(data.draw(st.integers(1, 2))):
        path = data.draw(st.sampled_from(_paths(raw) or PATHS[name]))
        _replace(raw, path, data.draw(yaml_hostile))
    file = tmp_path_factory.mktemp("fuzz") / f"{name}_mutated.yaml"
    try:
        file.write_text(yaml.safe_dump(raw, allow_unicode=True))
    except (yaml.YAMLError, RecursionError):
        return
    _load_or_config_error(file)


def _load_or_config_error(file) -> None:
    try:
        load_scenario(file)
    except ConfigError as exc:
        errors = exc.errors if isinstance(exc, ConfigErrors) else [exc]
        for e in errors:
            assert str(file) in e.source, str(e)
            assert e.path, f"no key named: {e}"


def _get(raw, path):
    for k in path:
        raw = raw[k]
    return raw


@pytest.mark.parametrize("name", FUZZED_SCENARIOS)
def test_every_number_of_a_scenario_at_the_ends_of_floats_loads_or_names_its_key(tmp_path, name):
    numbers = [
        p
        for p in PATHS[name]
        if isinstance(_get(SOURCES[name], p), (int, float))
        and not isinstance(_get(SOURCES[name], p), bool)
    ]
    file = tmp_path / f"{name}_extreme.yaml"
    # each number gets one of the three extremes in turn (all three on every number would triple
    # the run time of the suite's slowest fuzz test for no other fault class)
    extremes = (1e308, -1e308, 5e-324)
    for i, path in enumerate(numbers):
        raw = _copy(SOURCES[name])
        _replace(raw, path, extremes[i % 3])
        file.write_text(yaml.safe_dump(raw))
        _load_or_config_error(file)
