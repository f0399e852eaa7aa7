"""The planner's signed distance field as a browser view draws it: a frame on the planner's
diagnostics socket (port + 3, beside its ``diagnostics`` messages), made only while someone
subscribes to :data:`FIELD_TOPIC` (``m3p2i view`` does).

A frame is :data:`FIELD_TOPIC` followed by one msgpack map (arrays as
:func:`shared.protocol.encode_array` writes them; never pickle):

- ``v``: 1;
- ``time``: world seconds of the newest reading in the field;
- ``origin``: ``[x, y]`` the first cell's centre, m; ``resolution``: the cell's size, m;
- ``z`` (3-D fields only): the height of the horizontal slice, m, the layer nearest
  :data:`SLICE_ABOVE` above the grid's bottom face (a workspace box starts at the table top, so
  the slice shows what stands on it); a 2-D field, absent, lies on the floor;
- ``lo``, ``hi``: the distances (m) that 0 and 255 stand for;
- ``values``: ``[H, W]`` uint8, the signed distance clipped to ``[lo, hi]``:
  ``lo + values · (hi - lo) / 255``; at most :data:`MAX_SIDE` cells a side (a larger field is
  min-pooled, so an obstacle thinner than a pooled cell still shows).

At most :data:`FIELD_HZ` frames a wall second, each at most 40 kB of cells: a diagnostics reader
that does not know them finds no msgpack map in them and skips them. This module imports no
torch, so that the view reads the frames without it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from shared.protocol import ProtocolError, decode_array, encode_array

FIELD_TOPIC = b"field\x00"  # no msgpack map starts with "f": diagnostics readers skip it
FIELD_HZ = 2.0  # frames a wall second at most: the map changes at its own 10 Hz or less
MAX_SIDE = 200  # cells a side at most: 40 kB a frame, 80 kB/s at FIELD_HZ
LO, HI = -0.5, 1.5  # m: what the view colours (inside to 1 m, fading out by 1.5 m), 8 mm steps
SLICE_ABOVE = 0.05  # m above a 3-D grid's bottom face: its slice
MAX_FRAME = len(FIELD_TOPIC) + MAX_SIDE * MAX_SIDE + 1024
_MAX_COORD = 1e5  # m: as a scan's position (shared.scans)
_KEYS = {"v", "time", "origin", "resolution", "lo", "hi", "values"}


@dataclass(frozen=True)
class FieldSlice:
    """A field as drawn: quantised distances ``q`` ``[H, W]`` (uint8, rows along y, columns
    along x), the first cell's centre ``origin`` (x, y), the cell size ``resolution`` and the
    slice's height ``z`` (None: a 2-D field, on the floor), all m; ``time`` world s."""

    q: np.ndarray
    origin: tuple[float, float]
    resolution: float
    lo: float
    hi: float
    time: float
    z: float | None = None

    @property
    def distances(self) -> np.ndarray:
        """``[H, W]`` float32 signed distances, m, clipped to ``[lo, hi]``."""
        return (self.lo + self.q.astype(np.float32) * ((self.hi - self.lo) / 255)).astype(
            np.float32
        )

    def as_map(self) -> dict[str, Any]:
        """The frame's map (without the topic)."""
        out = {
            "v": 1,
            "time": float(self.time),
            "origin": [float(v) for v in self.origin],
            "resolution": float(self.resolution),
            "lo": float(self.lo),
            "hi": float(self.hi),
            "values": encode_array(np.ascontiguousarray(self.q, dtype=np.uint8)),
        }
        return out if self.z is None else out | {"z": float(self.z)}


def field_slice(field: Any) -> FieldSlice:
    """A :class:`planner_client.perception.field.DistanceField` (``values`` [H, W] or
    [D, H, W], torch or numpy) as the view draws it: a 3-D field's slice at
    :data:`SLICE_ABOVE` above its bottom face, min-pooled to at most :data:`MAX_SIDE` cells a
    side, clipped to [:data:`LO`, :data:`HI`] and quantised."""
    raw = field.values
    values = np.asarray(raw.detach().cpu() if hasattr(raw, "detach") else raw, dtype=float)
    res = float(field.resolution)
    z = None
    if values.ndim == 3:
        # the layer whose centre is nearest SLICE_ABOVE over the bottom face (res/2 under it)
        layer = min(max(round((SLICE_ABOVE - res / 2) / res), 0), len(values) - 1)
        values, z = values[layer], float(field.origin[2]) + layer * res
    stride = max(1, math.ceil(max(values.shape) / MAX_SIDE))
    if stride > 1:
        h, w = (math.ceil(n / stride) * stride for n in values.shape)
        padded = np.full((h, w), np.inf)
        padded[: values.shape[0], : values.shape[1]] = values
        values = padded.reshape(h // stride, stride, w // stride, stride).min(axis=(1, 3))
    shift = (stride - 1) / 2 * res  # a pooled cell's centre, from its first fine cell's
    q = np.rint((np.clip(values, LO, HI) - LO) / (HI - LO) * 255).astype(np.uint8)
    origin = (float(field.origin[0]) + shift, float(field.origin[1]) + shift)
    return FieldSlice(q, origin, res * stride, LO, HI, float(field.time), z)


def encode_field(field: Any) -> bytes:
    """One frame (topic and map) of ``field`` (:func:`field_slice`)."""
    return FIELD_TOPIC + msgpack.packb(field_slice(field).as_map(), use_bin_type=True)


def decode_field(frame: bytes) -> FieldSlice:
    """One frame -> :class:`FieldSlice`; :class:`ProtocolError` with the reason for anything
    malformed (another topic, not msgpack, unknown or missing keys, values not [H, W] uint8 of
    1 to :data:`MAX_SIDE` cells a side, numbers not finite or out of range)."""
    if not isinstance(frame, bytes) or not frame.startswith(FIELD_TOPIC):
        raise ProtocolError("field: the frame does not start with the field topic")
    if len(frame) > MAX_FRAME:
        raise ProtocolError(f"field: {len(frame)} bytes is over the limit {MAX_FRAME}")
    try:
        obj = msgpack.unpackb(frame[len(FIELD_TOPIC) :], raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise ProtocolError(f"field: not a msgpack map: {type(exc).__name__}: {exc}") from None
    return check_field_map(obj)


def check_field_map(obj: Any) -> FieldSlice:
    """A frame's map (or a recorded one: m3p2i/view) -> :class:`FieldSlice`, checked as
    :func:`decode_field` says."""
    if not isinstance(obj, dict):
        raise ProtocolError(f"field: expected a map, got {type(obj).__name__}")
    keys = set(obj)
    if not _KEYS <= keys or not keys <= _KEYS | {"z"}:
        raise ProtocolError(
            f"field: keys {sorted(map(str, keys))} (expected {sorted(_KEYS)}, and z for a slice)"
        )
    if obj["v"] != 1 or isinstance(obj["v"], bool):
        raise ProtocolError(f"field.v: {obj['v']!r} (this side reads 1)")
    values = decode_array(obj["values"], "field.values")
    if values.dtype != np.uint8 or values.ndim != 2 or not 0 < min(values.shape):
        raise ProtocolError(
            f"field.values: expected [H, W] uint8, got {list(values.shape)} {values.dtype}"
        )
    if max(values.shape) > MAX_SIDE:
        raise ProtocolError(f"field.values: {list(values.shape)} is over {MAX_SIDE} a side")
    origin = obj["origin"]
    if not (isinstance(origin, list) and len(origin) == 2):
        raise ProtocolError("field.origin: expected [x, y]")
    x, y = (_number(v, "field.origin", _MAX_COORD) for v in origin)
    res = _number(obj["resolution"], "field.resolution", 100.0)
    lo, hi = _number(obj["lo"], "field.lo", 100.0), _number(obj["hi"], "field.hi", 100.0)
    if res <= 0 or lo >= hi:
        raise ProtocolError(f"field: resolution {res} must be > 0 and lo {lo} < hi {hi}")
    when = _number(obj["time"], "field.time", 1e9)
    if when < 0:
        raise ProtocolError(f"field.time: {when} s (expected world seconds >= 0)")
    z = _number(obj["z"], "field.z", _MAX_COORD) if "z" in obj else None
    return FieldSlice(np.array(values), (x, y), res, lo, hi, when, z)


def _number(value: Any, what: str, limit: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{what}: expected a number, got {type(value).__name__}")
    if not math.isfinite(value) or abs(value) > limit:
        raise ProtocolError(f"{what}: {value} (expected a finite number within ±{limit:g})")
    return float(value)


class FieldPublisher:
    """The frames a planner sends: the newest field when it is new, at most ``hz`` a wall
    second (``clock``: seconds)."""

    def __init__(self, hz: float = FIELD_HZ, clock: Callable[[], float] = time.monotonic):
        self._period, self._clock = 1.0 / hz, clock
        self._sent: Any = None
        self._at = -math.inf

    def frame(self, field: Any) -> bytes | None:
        """The frame of ``field`` (a DistanceField, or None before the first), or None when it
        was sent already or one was sent less than a period ago."""
        now = self._clock()
        if field is None or field is self._sent or now - self._at < self._period:
            return None
        self._sent, self._at = field, now
        return encode_field(field)
