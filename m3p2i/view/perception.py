"""What the page draws of the robot's sensors and of the planner's map: each sensor's newest
returns as world-frame points (one colour per sensor), and the planner's signed distance field
as a heat map on a plane (a 2-D field just above the floor, a 3-D one at its slice's height:
:mod:`planner_client.perception.field_message`); the records of both in ``diagnostics.jsonl``
and what a replay reads back from them."""

from __future__ import annotations

import base64
import logging
import math
import threading
import zlib
from dataclasses import dataclass, field

import numpy as np

from planner_client.perception.field_message import (
    MAX_SIDE,
    FieldSlice,
    check_field_map,
)
from planner_client.perception.rays import world_points
from shared.protocol import ProtocolError
from shared.scans import Scan

log = logging.getLogger("m3p2i.view")

SCAN_COLOURS = [(255, 0, 220), (0, 190, 230), (250, 190, 0), (110, 210, 40)]
MAX_POINTS = 5000  # a sensor's points drawn (a depth camera's 76,800 returns, thinned)
MAX_RECORDED_POINTS = 2000  # a sensor's points in one record
RECORD_PERIOD = 0.5  # world s between a sensor's recorded scans: the replay's 2 Hz
FLOOR_Z = 0.01  # m: a 2-D field's plane, over the floor's (z = 0) and under everything on it
FADE = 1.0  # m: the heat map's blue, clear by 1.5 FADE (a smaller map's: fade_of)
# (distance as a fraction of the fade, RGB) stops of the colour ramp: red, yellow, blue
_RAMP = np.array([[0.0, 215, 30, 30], [0.35, 250, 200, 40], [1.0, 40, 110, 250]])
_INSIDE = (110, 0, 20, 230)  # an obstacle's inside: dark red, nearly opaque


def scan_points(scan: Scan, limit: int = MAX_POINTS) -> np.ndarray:
    """``[K, 3]`` float32: the returns within range as world-frame points (rays with none are
    left out), every n-th of them past ``limit``."""
    points = world_points(scan)
    if len(points) > limit:
        points = points[:: math.ceil(len(points) / limit)]
    return points.astype(np.float32)


def heat_rgba(distances: np.ndarray, fade: float = FADE) -> np.ndarray:
    """``[H, W, 4]`` uint8 colours of signed distances ``[H, W]`` (m): dark red inside an
    obstacle, red at its surface through yellow to blue at ``fade``, transparent from 1.5
    ``fade`` on. Row 0 is row 0 of the field."""
    d = np.asarray(distances, dtype=float)
    t = np.clip(d / fade, 0.0, 1.5)
    rgb = np.stack([np.interp(t, _RAMP[:, 0], _RAMP[:, c]) for c in (1, 2, 3)], axis=-1)
    alpha = np.where(t <= 1.0, 200 - 100 * t, 200 * (1.5 - t))
    out = np.concatenate([rgb, alpha[..., None]], axis=-1)
    out[d < 0] = _INSIDE
    return np.rint(out).astype(np.uint8)


def fade_of(fs: FieldSlice) -> float:
    """The distance (m) the heat map of ``fs`` turns blue at: :data:`FADE`, or a quarter of
    the map's narrower side where that is less (an arm's workspace)."""
    return min(FADE, min(fs.q.shape) * fs.resolution / 4)


class PerceptionDrawing:
    """The scan points (``/perception/scans/NAME``) and the heat map (``/perception/field``)
    in a viser scene, each layer shown or hidden as a whole (:meth:`add_toggles`)."""

    def __init__(self, server, sensors: list[str], scale: float):
        self.server = server
        self.colours = {n: SCAN_COLOURS[i % len(SCAN_COLOURS)] for i, n in enumerate(sensors)}
        self.point_size = max(0.005, 0.005 * scale)
        self.visible = {"scans": True, "field": True}
        # the panel's checkboxes call show() from viser's thread, the page's loop the setters
        self._lock = threading.Lock()
        self._clouds: dict[str, object] = {}
        self._field = None

    def add_toggles(self, gui) -> None:
        """Two checkboxes on the panel: the scan points, the distance map."""
        for layer, label, hint in (
            ("scans", "scan points", "Each sensor's newest returns, one colour per sensor."),
            ("field", "distance map", "The planner's signed distance field: red at obstacles."),
        ):
            box = gui.add_checkbox(label, True, hint=hint)
            box.on_update(lambda _, layer=layer, box=box: self.show(layer, box.value))

    def show(self, layer: str, visible: bool) -> None:
        """Show or hide a layer (``scans`` or ``field``)."""
        with self._lock:
            self.visible[layer] = visible
            nodes = list(self._clouds.values()) if layer == "scans" else [self._field]
            for node in nodes:
                if node is not None:
                    node.visible = visible

    def set_scans(self, scans: dict[str, np.ndarray]) -> None:
        """Each named sensor's points ``[K, 3]``; a sensor left out keeps its cloud."""
        with self._lock:
            for name, points in scans.items():
                node = self._clouds.pop(name, None)
                if node is not None:
                    node.remove()
                if len(points):
                    self._clouds[name] = self.server.scene.add_point_cloud(
                        f"/perception/scans/{name}",
                        np.asarray(points, np.float32),
                        self.colours.get(name, SCAN_COLOURS[0]),
                        point_size=self.point_size,
                        point_shape="circle",
                        visible=self.visible["scans"],
                    )

    def set_field(self, fs: FieldSlice | None) -> None:
        """The heat map of ``fs``, or none."""
        with self._lock:
            if self._field is not None:
                self._field.remove()
                self._field = None
            if fs is None:
                return
            h, w = fs.q.shape
            centre = np.array(fs.origin) + (np.array([w, h]) - 1) / 2 * fs.resolution
            rgba = heat_rgba(fs.distances, fade_of(fs))  # rows along the image's +y, as here
            self._field = self.server.scene.add_image(
                "/perception/field",
                rgba,
                w * fs.resolution,
                h * fs.resolution,
                format="png",
                cast_shadow=False,
                receive_shadow=False,
                position=(*centre, FLOOR_Z if fs.z is None else fs.z),
                visible=self.visible["field"],
            )


# ------------------------------------------------------------------------------ records


def scan_record(name: str, time: float, points: np.ndarray) -> dict:
    """A sensor's points as a ``diagnostics.jsonl`` record (mm, at most
    :data:`MAX_RECORDED_POINTS`)."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) > MAX_RECORDED_POINTS:
        points = points[:: math.ceil(len(points) / MAX_RECORDED_POINTS)]
    return {"kind": "scan", "name": name, "time": time, "points": np.round(points, 3).tolist()}


def field_record(fs: FieldSlice) -> dict:
    """A field as a ``diagnostics.jsonl`` record: the frame's numbers, and its cells
    zlib-compressed in base64 (a few kB: most of an arena is far from everything)."""
    out = {k: v for k, v in fs.as_map().items() if k != "values"}
    cells = base64.b64encode(zlib.compress(np.ascontiguousarray(fs.q).tobytes(), 6)).decode()
    return {"kind": "field", **out, "shape": list(fs.q.shape), "values": cells}


def field_from_record(rec: dict) -> FieldSlice:
    """A :func:`field_record` back, checked as a frame is
    (:func:`planner_client.perception.field_message.check_field_map`)."""
    rec = dict(rec)
    rec.pop("kind", None)
    shape, cells = rec.pop("shape", None), rec.pop("values", None)
    if not isinstance(cells, str) or not isinstance(shape, list):
        raise ProtocolError("field record: expected its shape and values")
    try:
        inflate = zlib.decompressobj()
        data = inflate.decompress(base64.b64decode(cells, validate=True), MAX_SIDE * MAX_SIDE + 1)
    except (ValueError, zlib.error) as exc:
        raise ProtocolError(f"field record: values are not zlib in base64 ({exc})") from None
    array = {"nd": True, "dtype": "|u1", "shape": shape, "data": data}
    return check_field_map(rec | {"values": array})


@dataclass
class PerceptionTrack:
    """A replay's recorded scans (by sensor) and fields, each in time order."""

    scans: dict[str, list[tuple[float, np.ndarray]]] = field(default_factory=dict)
    fields: list[FieldSlice] = field(default_factory=list)

    @classmethod
    def of(cls, records: list[dict]) -> PerceptionTrack:
        """From ``diagnostics.jsonl``'s ``scan`` and ``field`` records; a malformed one is
        skipped with a warning."""
        track = cls()
        for rec in records:
            try:
                if rec.get("kind") == "field":
                    track.fields.append(field_from_record(rec))
                elif rec.get("kind") == "scan":
                    points = np.asarray(rec["points"], dtype=np.float32).reshape(-1, 3)
                    if not (np.all(np.isfinite(points)) and math.isfinite(rec["time"])):
                        raise ValueError("points or time not finite")
                    track.scans.setdefault(str(rec["name"]), []).append(
                        (float(rec["time"]), points)
                    )
            except (KeyError, TypeError, ValueError) as exc:  # ProtocolError is a ValueError
                log.warning("skipped a recorded %s: %s", rec.get("kind"), exc)
        track.fields.sort(key=lambda f: f.time)
        for scans in track.scans.values():
            scans.sort(key=lambda s: s[0])
        return track

    def __bool__(self) -> bool:
        return bool(self.scans or self.fields)

    def scans_at(self, t: float) -> dict[str, np.ndarray]:
        """Each sensor's newest recorded points at or before ``t`` (none before its first)."""
        out = {}
        for name, scans in self.scans.items():
            i = _newest([s[0] for s in scans], t)
            out[name] = scans[i][1] if i >= 0 else np.zeros((0, 3), np.float32)
        return out

    def field_at(self, t: float) -> FieldSlice | None:
        """The newest recorded field at or before ``t``."""
        i = _newest([f.time for f in self.fields], t)
        return self.fields[i] if i >= 0 else None


def _newest(times: list[float], t: float) -> int:
    return int(np.searchsorted(np.asarray(times), t + 1e-9, side="right")) - 1
