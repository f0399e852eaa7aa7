"""Wire protocol between the world server (or a hardware bridge) and the planner client.

Every message is one ZeroMQ frame holding one msgpack map with at least ``type`` (str) and ``v``
(the protocol version, int). Arrays travel as plain maps ``{"nd": true, "dtype": "<f8",
"shape": [..], "data": <bytes>}`` — never pickle: decoding only ever builds dicts, lists,
numbers, strings and numpy arrays from raw bytes. The full specification, written for someone
implementing a bridge in another language, is ``docs/protocol.md``.

Decoding is strict: any malformed message raises :class:`ProtocolError` with the reason, and the
caller logs and drops it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from shared.scans import SCAN_KINDS, Scan, check_scan

PROTOCOL_VERSION = 4
"""3 added the sensors' readings (``state.scans``) and the anytime planner's ``samples``; 2 the
time-indexed plan of a command (``plan_*``), ``state.lag`` and the diagnostics' timing."""
VERSIONS = (1, 2, 3, 4)
"""The versions this code speaks: the planner's ``hello`` offers them, the world answers in the
highest both speak, and each side then encodes with that one (docs/protocol.md, "Version
negotiation"); a peer of none of them is refused with the versions named."""
VERSIONS_TEXT = ", ".join(map(str, VERSIONS))
MAX_MESSAGE_BYTES = 8 * 1024 * 1024
"""Frames above this are refused before decoding (ZMQ_MAXMSGSIZE is set to the same value)."""

MIN_PLAN_DT = 1e-6
"""Seconds: a command's ``plan_dt`` below this is refused (a microsecond is far under any
world's control period; a subnormal one would make the plan's index overflow)."""

MAX_SCANS = 64  # readings one state may carry (a sensor's every reading since the last state)

MAX_WORLD_TIME = 1e9
"""Seconds: a ``state.time`` outside ``[0, MAX_WORLD_TIME]`` (about 31 years of world time) is
refused. A world's time counts from its episode's start; one near float64's top would make the
planner's step counts (time / dt) overflow every integer."""

MAX_SEED = 2**32 - 1  # an episode's seed (welcome.seed, a reset's control.seed)

_DTYPES = {"<f8", "<f4", "<i4", "<i8", "|u1", "|b1"}
_MAX_ARRAY_ELEMENTS = 4_000_000
_MAX_ARRAY_DIMS = 4


class ProtocolError(ValueError):
    """A message that cannot be accepted; the text says why."""


# ---------------------------------------------------------------- arrays


def encode_array(a: np.ndarray) -> dict:
    """Array -> plain msgpack map (little-endian, C order)."""
    a = np.ascontiguousarray(a)
    if a.dtype.kind == "f":
        a = a.astype("<f8" if a.dtype.itemsize == 8 else "<f4", copy=False)
    elif a.dtype.kind in "iu" and a.dtype.itemsize > 1:
        a = a.astype("<i8" if a.dtype.itemsize == 8 else "<i4", copy=False)
    dtype = a.dtype.str
    if dtype not in _DTYPES:
        raise ProtocolError(f"cannot send arrays of dtype {a.dtype}")
    return {"nd": True, "dtype": dtype, "shape": list(a.shape), "data": a.tobytes()}


def decode_array(obj: Any, what: str) -> np.ndarray:
    """Plain map -> read-only numpy array, checking dtype, shape and byte count."""
    if not isinstance(obj, dict) or obj.get("nd") is not True:
        raise ProtocolError(f"{what}: expected an array map {{nd, dtype, shape, data}}")
    dtype, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("data")
    if not isinstance(dtype, str) or dtype not in _DTYPES:
        raise ProtocolError(
            f"{what}: unsupported dtype {dtype!r} (expected one of {sorted(_DTYPES)})"
        )
    if (
        not isinstance(shape, list)
        or len(shape) > _MAX_ARRAY_DIMS
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise ProtocolError(f"{what}: bad shape {shape!r}")
    if any(n > _MAX_ARRAY_ELEMENTS for n in shape):
        raise ProtocolError(
            f"{what}: shape {shape} has a dimension over the limit {_MAX_ARRAY_ELEMENTS}"
        )
    count = math.prod(shape)  # exact (np.prod wraps around in int64: 2**63 · 2 is 0)
    if count > _MAX_ARRAY_ELEMENTS:
        raise ProtocolError(f"{what}: {count} elements is over the limit {_MAX_ARRAY_ELEMENTS}")
    if not isinstance(data, bytes) or len(data) != count * np.dtype(dtype).itemsize:
        size = len(data) if isinstance(data, bytes) else type(data).__name__
        raise ProtocolError(
            f"{what}: data has {size} bytes, shape {shape} of {dtype} needs "
            f"{count * np.dtype(dtype).itemsize}"
        )
    arr = np.frombuffer(data, dtype=dtype).reshape(shape)
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ProtocolError(f"{what}: contains NaN or inf")
    return arr


# ---------------------------------------------------------------- messages


@dataclass
class Hello:
    """Planner -> server (control socket, request): who I am and what I loaded."""

    scenario: str
    scenario_hash: str
    client: str = "m3p2i-planner"
    versions: list[int] | None = None  # the versions the planner speaks (None: only the hello's v)
    robot: str | None = None  # in a world of several robots: the one this planner drives
    type = "hello"


@dataclass
class Welcome:
    """Server -> planner (control reply): handshake accepted, and how the world runs."""

    scenario: str
    scenario_hash: str
    mode: str  # "lockstep" | "realtime"
    dt: float  # seconds of simulated time per world step
    nu: int  # length of Command.ctrl
    session: str  # changes when the server restarts; commands echo it
    seed: int | None = None  # a kept world's episode seed: the planner reseeds its sampling with it
    type = "welcome"


@dataclass
class State:
    """Server -> planner (PUB): the full physics state after world step ``seq``.

    ``qpos``/``qvel`` in MuJoCo's generalised coordinates of the scenario's model; ``act`` and
    ``mocap_*`` may be empty when the model has none. ``extras`` holds named scalars the world
    simulates beside the physics (e.g. ``battery`` in percent). ``status`` is "running" until the
    episode ends ("success", "timeout", "stopped").
    """

    session: str
    seq: int
    time: float
    qpos: np.ndarray
    qvel: np.ndarray
    act: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    status: str = "running"
    extras: dict[str, float] = field(default_factory=dict)
    lag: float = 0.0  # world s from publishing the state a command answered to its arrival
    scans: list[Scan] = field(default_factory=list)  # readings due since the previous state
    plans: list[RobotPlan] = field(default_factory=list)  # every robot's newest plan (a team's)
    type = "state"


@dataclass
class RobotPlan:
    """A team robot's newest plan as the world forwards it to the others' planners (protocol 4):
    ``ctrl [H, nu]`` of that robot for world times ``t0 + i·dt``."""

    robot: str
    t0: float
    dt: float
    ctrl: np.ndarray


@dataclass
class Command:
    """Planner -> server (PUSH): the control answering state ``seq`` of ``session``.

    ``ctrl`` is the control for now (all a world that holds one control needs); the optional plan
    is the whole planned sequence ``plan_ctrl [H, nu]`` for world times ``plan_t0 + i·plan_dt``,
    played with zero-order hold by a world that does not wait (:mod:`shared.timed_plan`).
    """

    session: str
    seq: int
    ctrl: np.ndarray
    plan_time: float = 0.0  # seconds the planner spent on this command (for Hz statistics)
    action: str = ""  # the task-level action being executed, for the episode log
    plan_ctrl: np.ndarray | None = None
    plan_t0: float | None = None
    plan_dt: float | None = None
    # the planner's identified model, "kind.name" -> factor (planner.model.variants.identify)
    model: dict[str, float] | None = None
    samples: int | None = None  # samples per mode now, under a planner.budget (else None)
    robot: str | None = None  # in a world of several robots: whose controls ``ctrl`` are
    type = "command"

    @property
    def has_plan(self) -> bool:
        return self.plan_ctrl is not None


@dataclass
class Diagnostics:
    """Planner -> viewers (PUB): what the planner is thinking, for viewers and recorders.

    ``top`` are the positions ([M, T, 3]) of the best sampled trajectories' robot frame;
    ``top_modes`` ([M], optional) the index in ``mode_names`` of each one's mode; ``guide``
    ([N, 3], optional) the corners of the scenario guide's path (docs/scenarios.md).
    """

    seq: int
    action: str
    alternatives: list[str]
    mode_names: list[str]
    mode_weights: np.ndarray
    top: np.ndarray
    plan_time: float
    lead: float = 0.0  # world s the plan was predicted ahead of the state (its expected lag)
    steps: int = 0  # world steps since the state the previous plan answered
    top_modes: np.ndarray | None = None
    model: dict[str, float] | None = None  # as Command.model
    guide: np.ndarray | None = None
    samples: int | None = None  # as Command.samples
    type = "diagnostics"


@dataclass
class Error:
    """Either side: a refusal (e.g. handshake mismatch) with a human-readable reason.
    ``versions``: the versions the world speaks, in its answer to a ``hello`` that offered some
    (it tells a planner that the world negotiated, so that it does not retry in another form)."""

    reason: str
    versions: list[int] | None = None
    type = "error"


@dataclass
class Control:
    """Launcher/tools -> server (control socket): ``reset`` the episode, ``shutdown``,
    ``pause`` / ``resume`` the world's clock, or ``move`` a scenario object to ``pos [3]``
    (world frame, m) and optionally ``quat [4]`` (w, x, y, z): a disturbance from a tool such as
    ``m3p2i view``. ``reset`` with ``seed`` ends the episode and begins a new one from that
    seed's start (a world started with ``--keep-serving`` only: warm bench workers). The world
    echoes an accepted op and answers ``error`` with the reason else."""

    op: str
    object: str | None = None
    pos: np.ndarray | None = None
    quat: np.ndarray | None = None
    seed: int | None = None
    type = "control"


MESSAGES = {cls.type: cls for cls in (Hello, Welcome, State, Command, Diagnostics, Error, Control)}

# field name -> (kind, required); kinds: str, int, float, array, strlist, intlist, floatmap
_SCHEMA: dict[str, dict[str, tuple[str, bool]]] = {
    "hello": {
        "scenario": ("str", True),
        "scenario_hash": ("str", True),
        "client": ("str", False),
        "versions": ("intlist", False),
        "robot": ("str", False),
    },
    "welcome": {
        "scenario": ("str", True),
        "scenario_hash": ("str", True),
        "mode": ("str", True),
        "dt": ("float", True),
        "nu": ("int", True),
        "session": ("str", True),
        "seed": ("int", False),
    },
    "state": {
        "session": ("str", True),
        "seq": ("int", True),
        "time": ("float", True),
        "qpos": ("array", True),
        "qvel": ("array", True),
        "act": ("array", True),
        "mocap_pos": ("array", True),
        "mocap_quat": ("array", True),
        "status": ("str", False),
        "extras": ("floatmap", False),
        "lag": ("float", False),
        "scans": ("scans", False),
        "plans": ("plans", False),
    },
    "command": {
        "session": ("str", True),
        "seq": ("int", True),
        "ctrl": ("array", True),
        "plan_time": ("float", False),
        "action": ("str", False),
        "plan_ctrl": ("array", False),
        "plan_t0": ("float", False),
        "plan_dt": ("float", False),
        "model": ("floatmap", False),
        "samples": ("int", False),
        "robot": ("str", False),
    },
    "diagnostics": {
        "seq": ("int", True),
        "action": ("str", True),
        "alternatives": ("strlist", True),
        "mode_names": ("strlist", True),
        "mode_weights": ("array", True),
        "top": ("array", True),
        "plan_time": ("float", True),
        "lead": ("float", False),
        "steps": ("int", False),
        "top_modes": ("array", False),
        "model": ("floatmap", False),
        "guide": ("array", False),
        "samples": ("int", False),
    },
    "error": {"reason": ("str", True), "versions": ("intlist", False)},
    "control": {
        "op": ("str", True),
        "object": ("str", False),
        "pos": ("array", False),
        "quat": ("array", False),
        "seed": ("int", False),
    },
}
# each version is the next without these fields (docs/protocol.md); hello.versions and
# error.versions, the negotiation, are read in all
_NOT_IN_V3 = {"hello": {"robot"}, "state": {"plans"}, "command": {"robot"}}
_NOT_IN_V2 = {"state": {"scans"}, "command": {"samples"}, "diagnostics": {"samples"}}
_NOT_IN_V1 = {
    "welcome": {"seed"},
    "state": {"lag"},
    "command": {"plan_ctrl", "plan_t0", "plan_dt", "model"},
    "diagnostics": {"lead", "steps", "top_modes", "model", "guide"},
    "control": {"object", "pos", "quat", "seed"},
}
_SCHEMAS = {
    version: {
        kind: {
            name: spec
            for name, spec in fields.items()
            if not any(name in table.get(kind, ()) for table in left_out)
        }
        for kind, fields in _SCHEMA.items()
    }
    for version, left_out in (
        (4, ()),
        (3, (_NOT_IN_V3,)),
        (2, (_NOT_IN_V3, _NOT_IN_V2)),
        (1, (_NOT_IN_V3, _NOT_IN_V2, _NOT_IN_V1)),
    )
}
_STATUSES = {"running", "success", "timeout", "stopped"}
_MODES = {"lockstep", "realtime"}
_OPS = {"reset", "shutdown", "pause", "resume", "move"}


def encode(msg: Any, version: int = PROTOCOL_VERSION) -> bytes:
    """Message dataclass -> one msgpack frame in protocol ``version`` (one of :data:`VERSIONS`):
    fields that version does not have are left out (a version-1 command carries no plan)."""
    if version not in _SCHEMAS:
        raise ProtocolError(
            f"cannot encode protocol version {version} (this side speaks {version_names(VERSIONS)})"
        )
    out: dict[str, Any] = {"type": msg.type, "v": version}
    for name, (kind, required) in _SCHEMAS[version][msg.type].items():
        value = getattr(msg, name)
        if (value is None or (kind in ("scans", "plans") and not value)) and not required:
            continue
        if kind == "scans":
            value = [_scan_map(scan) for scan in value]
        elif kind == "plans":
            value = [p.__dict__ | {"ctrl": encode_array(np.asarray(p.ctrl))} for p in value]
        elif kind == "array":
            value = encode_array(np.asarray(value))
        elif kind == "floatmap":
            value = {str(k): float(v) for k, v in value.items()}
        elif kind == "strlist":
            value = [str(v) for v in value]
        elif kind == "intlist":
            value = [int(v) for v in value]
        out[name] = value
    frame = msgpack.packb(out, use_bin_type=True)
    if len(frame) > MAX_MESSAGE_BYTES:
        raise ProtocolError(
            f"{msg.type} message of {len(frame)} bytes is over the limit {MAX_MESSAGE_BYTES}"
        )
    return frame


def decode(
    frame: bytes,
    expect: str | tuple[str, ...] | None = None,
    versions: tuple[int, ...] = (PROTOCOL_VERSION,),
) -> Any:
    """One frame -> message dataclass; raises :class:`ProtocolError` for anything malformed.

    Args:
        frame: the raw bytes received.
        expect: message type(s) acceptable on this socket; others are refused.
        versions: the protocol versions accepted (each read with its own fields).
    """
    return decode_versioned(frame, expect, versions)[0]


def decode_versioned(
    frame: bytes,
    expect: str | tuple[str, ...] | None = None,
    versions: tuple[int, ...] = (PROTOCOL_VERSION,),
) -> tuple[Any, int]:
    """:func:`decode`, and the version the frame was written in. An ``error`` is read at any
    version (its ``reason``, and ``versions`` when valid): a refused peer must learn why."""
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise ProtocolError("frame is not bytes")
    if len(frame) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"message of {len(frame)} bytes is over the limit {MAX_MESSAGE_BYTES}")
    try:
        obj = msgpack.unpackb(bytes(frame), raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise ProtocolError(f"not a msgpack message: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, dict):
        raise ProtocolError(f"message must be a map, got {type(obj).__name__}")
    kind = obj.get("type")
    if not isinstance(kind, str) or kind not in _SCHEMA:
        raise ProtocolError(f"unknown message type {kind!r} (expected one of {sorted(_SCHEMA)})")
    if expect is not None and kind not in ((expect,) if isinstance(expect, str) else expect):
        raise ProtocolError(f"unexpected message type {kind!r} here (expected {expect})")
    version = obj.get("v")
    # an error's reason is read at any version: a refused peer must learn why, not just "v3?"
    readable_error = (
        kind == "error"
        and isinstance(version, int)
        and not isinstance(version, bool)
        and isinstance(obj.get("reason"), str)
    )
    known = version in versions and version in _SCHEMAS
    if not known and not readable_error:
        offered = obj.get("versions") if kind == "hello" else None
        if _is_intlist(offered) and not set(offered) & set(versions):
            raise ProtocolError(
                f"no common protocol version: the peer speaks "
                f"{version_names(offered)}, this side speaks {version_names(versions)}"
            )
        if _is_intlist(offered):  # a version in common: the frame's own v is what is wrong
            raise ProtocolError(
                f"hello written in protocol version {version!r}, which this side does not "
                f"read: a hello offering {version_names(offered)} is written in one this side "
                f"speaks ({version_names(versions)}), the oldest it offers"
            )
        raise ProtocolError(
            f"protocol version {version!r} not supported "
            f"(this side speaks {version_names(versions)})"
        )
    if not known:
        theirs = obj.get("versions")
        return Error(
            reason=obj["reason"][:4096], versions=list(theirs)[:64] if _is_intlist(theirs) else None
        ), version
    schema = _SCHEMAS[version][kind]
    unknown = set(obj) - set(schema) - {"type", "v"}
    if unknown:
        raise ProtocolError(f"{kind}: unknown field(s) {sorted(map(str, unknown))}")
    fields = {}
    for name, (ftype, required) in schema.items():
        if name not in obj:
            if required:
                raise ProtocolError(f"{kind}: missing field {name!r}")
            continue
        fields[name] = _check_field(kind, name, ftype, obj[name])
    msg = MESSAGES[kind](**fields)
    _check_values(msg)
    return msg, version


def _is_intlist(value: Any) -> bool:
    return (
        isinstance(value, list)
        and 0 < len(value) <= 64
        and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    )


def version_names(versions) -> str:
    """``version 2`` or ``versions 1, 2``: for messages naming a side's versions."""
    versions = list(versions)
    return f"version{'s' if len(versions) != 1 else ''} {', '.join(str(v) for v in versions)}"


def _check_field(kind: str, name: str, ftype: str, value: Any) -> Any:
    what = f"{kind}.{name}"
    if ftype == "str":
        if not isinstance(value, str) or len(value) > 4096:
            raise ProtocolError(f"{what}: expected a string")
        return value
    if ftype == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ProtocolError(f"{what}: expected an integer, got {type(value).__name__}")
        return value
    if ftype == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise ProtocolError(f"{what}: expected a finite number")
        return float(value)
    if ftype == "array":
        return decode_array(value, what)
    if ftype == "strlist":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ProtocolError(f"{what}: expected a list of strings")
        return value
    if ftype == "intlist":
        if not _is_intlist(value):
            raise ProtocolError(f"{what}: expected a list of 1 to 64 integers")
        return list(value)
    if ftype == "scans":
        if not isinstance(value, list) or len(value) > MAX_SCANS:
            raise ProtocolError(f"{what}: expected a list of at most {MAX_SCANS} scan maps")
        return [_decode_scan(item, f"{what}[{i}]") for i, item in enumerate(value)]
    if ftype == "plans":
        if not isinstance(value, list) or len(value) > 64:
            raise ProtocolError(f"{what}: expected a list of at most 64 plan maps")
        return [_decode_plan(item, f"{what}[{i}]") for i, item in enumerate(value)]
    if ftype == "floatmap":
        if not isinstance(value, dict) or not all(
            isinstance(k, str)
            and isinstance(v, (int, float))
            and not isinstance(v, bool)
            and math.isfinite(v)
            for k, v in value.items()
        ):
            raise ProtocolError(f"{what}: expected a map of names to finite numbers")
        return {k: float(v) for k, v in value.items()}
    raise AssertionError(ftype)


def _decode_plan(obj: Any, what: str) -> RobotPlan:
    """One plan map -> a :class:`RobotPlan`: its fields, ``dt`` > 0, ``ctrl`` 2-D."""
    fields = {"robot": "str", "t0": "float", "dt": "float", "ctrl": "array"}
    if not isinstance(obj, dict) or set(obj) != set(fields):
        raise ProtocolError(f"{what}: expected a map of exactly {', '.join(fields)}")
    plan = RobotPlan(**{k: _check_field(what, k, t, obj[k]) for k, t in fields.items()})
    if plan.dt < MIN_PLAN_DT or plan.ctrl.ndim != 2 or len(plan.ctrl) == 0:
        raise ProtocolError(f"{what}: dt must be > 0 and ctrl [H >= 1, nu]")
    return plan


# a scan's fields (docs/protocol.md, "Scans"), and those of each kind
_SCAN_FIELDS = {
    "name": "str",
    "kind": "str",
    "time": "float",
    "pos": "array",
    "quat": "array",
    "ranges": "array",
    "range_min": "float",
    "range_max": "float",
}
_SCAN_KIND_FIELDS = {"lidar": ("angle_min", "angle_increment"), "depth": ("fovy",)}


def _scan_map(scan: Scan) -> dict:
    """A :class:`Scan` as the plain map a state carries: the common fields and its kind's."""
    out = {
        name: (
            encode_array(np.asarray(getattr(scan, name), dtype=float))
            if ftype == "array"
            else getattr(scan, name)
        )
        for name, ftype in _SCAN_FIELDS.items()
    }
    return out | {name: float(getattr(scan, name)) for name in _SCAN_KIND_FIELDS[scan.kind]}


def _decode_scan(obj: Any, what: str) -> Scan:
    """One scan map -> a checked :class:`Scan` (:func:`shared.scans.check_scan`)."""
    if not isinstance(obj, dict):
        raise ProtocolError(f"{what}: expected a scan map, got {type(obj).__name__}")
    kind = obj.get("kind")
    if not isinstance(kind, str) or kind not in SCAN_KINDS:
        raise ProtocolError(f"{what}.kind: {kind!r} (expected one of {', '.join(SCAN_KINDS)})")
    schema = _SCAN_FIELDS | dict.fromkeys(_SCAN_KIND_FIELDS[kind], "float")
    unknown = set(obj) - set(schema)
    if unknown:
        raise ProtocolError(
            f"{what}: unknown field(s) for a {kind} scan {sorted(map(str, unknown))}"
        )
    missing = [name for name in schema if name not in obj]
    if missing:
        raise ProtocolError(f"{what}: missing field(s) {missing}")
    fields = {name: _check_field(what, name, ftype, obj[name]) for name, ftype in schema.items()}
    try:
        return check_scan(Scan(**fields))
    except ValueError as exc:
        raise ProtocolError(f"{what}: {exc}") from None


def _check_values(msg: Any) -> None:
    if isinstance(msg, State) and msg.status not in _STATUSES:
        raise ProtocolError(f"state.status: {msg.status!r} (expected one of {sorted(_STATUSES)})")
    if isinstance(msg, Welcome):
        _check_welcome(msg)
    if isinstance(msg, Control):
        _check_control(msg)
    if isinstance(msg, (State, Command)) and msg.seq < 0:
        raise ProtocolError(f"{msg.type}.seq must be >= 0")
    if isinstance(msg, Command):
        if msg.ctrl.ndim != 1:
            raise ProtocolError(f"command.ctrl: expected shape [nu], got {list(msg.ctrl.shape)}")
        _check_plan(msg)
    if (
        isinstance(msg, Diagnostics)
        and msg.top_modes is not None
        and msg.top_modes.shape != msg.top.shape[:1]
    ):
        raise ProtocolError(
            f"diagnostics.top_modes: expected shape [{msg.top.shape[0]}] (one "
            f"per trajectory of top), got {list(msg.top_modes.shape)}"
        )
    if (
        isinstance(msg, Diagnostics)
        and msg.guide is not None
        and (msg.guide.ndim != 2 or msg.guide.shape[1] != 3)
    ):
        raise ProtocolError(
            f"diagnostics.guide: expected shape [N, 3] (the path's corners), "
            f"got {list(msg.guide.shape)}"
        )
    if isinstance(msg, State) and not 0 <= msg.lag <= MAX_WORLD_TIME:
        raise ProtocolError(f"state.lag: {msg.lag} s (expected world seconds in [0, 1e9])")
    if isinstance(msg, State) and not 0 <= msg.time <= MAX_WORLD_TIME:
        raise ProtocolError(
            f"state.time: {msg.time} s (expected world seconds since the episode's start, "
            f"in [0, {MAX_WORLD_TIME:g}])"
        )
    if isinstance(msg, State):
        _check_state_shapes(msg)
    if isinstance(msg, Diagnostics):
        if msg.mode_weights.ndim != 1:
            raise ProtocolError(
                f"diagnostics.mode_weights: expected shape [N] (one per mode), "
                f"got {list(msg.mode_weights.shape)}"
            )
        if msg.top.ndim != 3 or msg.top.shape[2] != 3:
            raise ProtocolError(
                f"diagnostics.top: expected shape [M, T, 3], got {list(msg.top.shape)}"
            )


def _check_state_shapes(msg: State) -> None:
    """``qpos``, ``qvel``, ``act`` [n]; ``mocap_pos`` [nmocap, 3] and ``mocap_quat`` [nmocap, 4]
    (both empty, of any shape, for a model without mocap bodies)."""
    for name in ("qpos", "qvel", "act"):
        if getattr(msg, name).ndim != 1:
            raise ProtocolError(
                f"state.{name}: expected shape [n], got {list(getattr(msg, name).shape)}"
            )
    pos, quat = msg.mocap_pos, msg.mocap_quat
    if pos.size == 0 and quat.size == 0:
        return
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ProtocolError(f"state.mocap_pos: expected shape [nmocap, 3], got {list(pos.shape)}")
    if quat.shape != (pos.shape[0], 4):
        raise ProtocolError(
            f"state.mocap_quat: expected shape [{pos.shape[0]}, 4] (as "
            f"mocap_pos), got {list(quat.shape)}"
        )


def _check_welcome(msg: Welcome) -> None:
    """The world's step as the scenario loader allows it (a microsecond to 10 s), ``nu >= 0``,
    a seed as ``control`` takes one."""
    if msg.mode not in _MODES:
        raise ProtocolError(f"welcome.mode: {msg.mode!r} (expected one of {sorted(_MODES)})")
    if not MIN_PLAN_DT <= msg.dt <= 10.0:
        raise ProtocolError(f"welcome.dt: {msg.dt} s (expected seconds in [{MIN_PLAN_DT}, 10])")
    if msg.nu < 0:
        raise ProtocolError(f"welcome.nu: {msg.nu} (expected >= 0)")
    if msg.seed is not None and not 0 <= msg.seed <= MAX_SEED:
        raise ProtocolError(f"welcome.seed: {msg.seed} (expected 0 <= seed < 2**32)")


def _check_plan(cmd: Command) -> None:
    given = [name for name in ("plan_ctrl", "plan_t0", "plan_dt") if getattr(cmd, name) is not None]
    if not given:
        return
    if len(given) != 3:
        raise ProtocolError(
            f"command: a plan needs plan_ctrl, plan_t0 and plan_dt together, got {given}"
        )
    if (
        cmd.plan_ctrl.ndim != 2
        or cmd.plan_ctrl.shape[0] < 1
        or cmd.plan_ctrl.shape[1] != cmd.ctrl.shape[0]
    ):
        raise ProtocolError(
            f"command.plan_ctrl: expected shape [H >= 1, {cmd.ctrl.shape[0]}] "
            f"(nu of ctrl), got {list(cmd.plan_ctrl.shape)}"
        )
    if cmd.plan_dt <= 0:
        raise ProtocolError(f"command.plan_dt must be > 0, got {cmd.plan_dt}")
    if cmd.plan_dt < MIN_PLAN_DT:
        raise ProtocolError(
            f"command.plan_dt must be >= {MIN_PLAN_DT} s, got {cmd.plan_dt}: no "
            f"world plays controls that short, and a world's tick would index "
            f"its plan past any integer"
        )
    if not np.isfinite(cmd.plan_t0 + cmd.plan_ctrl.shape[0] * cmd.plan_dt):
        raise ProtocolError(
            f"command: the plan must end at a finite world time, got plan_t0 "
            f"{cmd.plan_t0} + {cmd.plan_ctrl.shape[0]} knots x plan_dt "
            f"{cmd.plan_dt}"
        )


def _check_control(msg: Control) -> None:
    """``move`` needs ``object`` and ``pos [3]`` (``quat [4]``, non-zero, optional); ``reset``
    may carry a ``seed`` (0 <= seed < 2**32); the other ops carry none of them (a stray field
    means a confused sender)."""
    if msg.op not in _OPS:
        raise ProtocolError(f"control.op: {msg.op!r} (expected one of {sorted(_OPS)})")
    if msg.seed is not None and msg.op != "reset":
        raise ProtocolError(f"control.op {msg.op!r} takes no seed (only 'reset' does)")
    if msg.seed is not None and not 0 <= msg.seed <= MAX_SEED:
        raise ProtocolError(f"control.seed: {msg.seed} (expected 0 <= seed < 2**32)")
    if msg.op != "move":
        extra = [n for n in ("object", "pos", "quat") if getattr(msg, n) is not None]
        if extra:
            raise ProtocolError(
                f"control.op {msg.op!r} takes no {', '.join(extra)} (only 'move' does)"
            )
        return
    if not msg.object or msg.pos is None:
        raise ProtocolError(
            "control.op 'move' needs 'object' (a scenario object's name) and 'pos' [3]"
        )
    if msg.pos.shape != (3,):
        raise ProtocolError(
            f"control.pos: expected shape [3] (x, y, z in m), got {list(msg.pos.shape)}"
        )
    if msg.quat is not None and (msg.quat.shape != (4,) or not np.linalg.norm(msg.quat) > 1e-9):
        raise ProtocolError(
            f"control.quat: expected a non-zero quaternion [4] (w, x, y, z), got "
            f"{np.asarray(msg.quat).tolist()}"
        )
