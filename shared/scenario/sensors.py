"""The scenario's ``sensors:`` list: range sensors the world simulates, a 2-D lidar and a depth
camera, whose readings travel with its states as :class:`shared.scans.Scan` (``server/sensors.py``
simulates them; docs/scenarios.md, "Sensors"). Read and bounded here, at load; their frames are
names of the world's model, checked by the world (``server/world_check.py``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from shared.config import ErrorLog, Section, number, one_of, positive_int, vector
from shared.scans import MAX_NAME, MAX_PIXELS, MAX_RAYS, SCAN_KINDS

SENSOR_TYPES = SCAN_KINDS
MAX_RATE = 100.0  # readings per world second
MAX_RANGE = 1000.0  # m
WORLD_FRAME = "world"  # a sensor fixed in the world


@dataclass(frozen=True)
class LidarConfig:
    """A 2-D lidar at ``pos`` (m) in ``frame`` (``robot``, a body, ``site:NAME`` or ``world``),
    turned as that frame: ``rays`` rays over ``fov`` degrees of its x-y plane centred on its x
    axis, ``range`` [min, max] m, a reading every 1/``rate`` world seconds."""

    name: str
    frame: str = "robot"
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rays: int = 180
    fov: float = 360.0
    range: tuple[float, float] = (0.05, 8.0)
    rate: float = 10.0
    kind = "lidar"


@dataclass(frozen=True)
class DepthConfig:
    """A depth camera at ``pos`` (m) in ``frame``, looking along its own +z (OpenCV's axes:
    image x along its +x, rows along its +y), turned from ``frame`` by ``euler`` (degrees about
    x, then the new y, then the new z: MuJoCo's ``xyz``) or towards ``look_at`` (a point in
    ``frame``; the image's up towards the frame's +z); neither: as ``frame``. ``width`` x
    ``height`` pixels, vertical field of view ``fovy`` degrees, ``range`` and ``rate`` as a
    lidar's."""

    name: str
    frame: str = WORLD_FRAME
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] | None = None
    look_at: tuple[float, float, float] | None = None
    width: int = 80
    height: int = 60
    fovy: float = 58.0
    range: tuple[float, float] = (0.1, 5.0)
    rate: float = 10.0
    kind = "depth"


SensorConfig = LidarConfig | DepthConfig


def read_sensors(top: Section, errors: ErrorLog) -> tuple[SensorConfig, ...]:
    """``sensors:``, each fault recorded in ``errors`` (a faulty sensor is left out)."""
    out: list[SensorConfig] = []
    for s in errors.call(top.items, "sensors", default=[]):
        sensor = errors.call(_sensor, s)
        if sensor is not None and sensor.name in {o.name for o in out}:
            errors.add(s.error("name", "two sensors of one name", sensor.name, "a unique name"))
        elif sensor is not None:
            out.append(sensor)
    return tuple(out)


def _sensor(s: Section) -> SensorConfig:
    kind = s.req("type", one_of(SENSOR_TYPES))
    cls = LidarConfig if kind == "lidar" else DepthConfig
    common = dict(
        name=s.req("name", _name, f"a name of 1 to {MAX_NAME} characters"),
        frame=s.opt("frame", cls.frame, str, "robot, a body, site:NAME or world"),
        pos=s.opt("pos", cls.pos, vector(3), "[x, y, z] in metres, in frame"),
        range=s.opt("range", cls.range, _range, f"[min, max] m, 0 <= min < max <= {MAX_RANGE:g}"),
        rate=s.opt("rate", cls.rate, _rate, f"readings per second in (0, {MAX_RATE:g}]"),
    )
    if kind == "lidar":
        cfg = LidarConfig(
            rays=s.opt("rays", 180, _bounded_int(MAX_RAYS), f"an integer in [1, {MAX_RAYS}]"),
            fov=s.opt("fov", 360.0, _angle(360.0, closed=True), "degrees in (0, 360]"),
            **common,
        )
    else:
        if s.has("euler") and s.has("look_at"):
            raise s.error("look_at", "give either euler or look_at, not both", s.data["look_at"])
        cfg = DepthConfig(
            euler=s.opt("euler", None, vector(3), "[x, y, z] degrees"),
            look_at=s.opt("look_at", None, vector(3), "[x, y, z] in metres, in frame"),
            width=s.opt("width", 80, positive_int, "pixels, an integer > 0"),
            height=s.opt("height", 60, positive_int, "pixels, an integer > 0"),
            fovy=s.opt("fovy", 58.0, _angle(180.0, closed=False), "degrees in (0, 180)"),
            **common,
        )
        if cfg.width * cfg.height > MAX_PIXELS:
            raise s.error(
                "width",
                f"{cfg.width} x {cfg.height} pixels is over the limit",
                cfg.width,
                f"width x height <= {MAX_PIXELS} (320 x 240)",
            )
        if cfg.look_at is not None and cfg.look_at == cfg.pos:
            raise s.error("look_at", "is the camera's own position", list(cfg.look_at))
    s.done()
    return cfg


def _name(value: Any) -> str:
    if not isinstance(value, str) or not 0 < len(value) <= MAX_NAME:
        raise ValueError(f"must be a string of 1 to {MAX_NAME} characters")
    return value


def _range(value: Any) -> tuple[float, float]:
    lo, hi = vector(2)(value)
    if not 0.0 <= lo < hi <= MAX_RANGE:
        raise ValueError(f"must be [min, max] with 0 <= min < max <= {MAX_RANGE:g}")
    return lo, hi


def _rate(value: Any) -> float:
    v = number(value)
    if not 0.0 < v <= MAX_RATE:
        raise ValueError(f"must be in (0, {MAX_RATE:g}]")
    return v


def _bounded_int(top: int):
    def convert(value: Any) -> int:
        v = positive_int(value)
        if v > top:
            raise ValueError(f"must be at most {top}")
        return v

    return convert


def _angle(top: float, closed: bool):
    def convert(value: Any) -> float:
        v = number(value)
        if not (0.0 < v <= top if closed else 0.0 < v < top):
            raise ValueError(f"must be in (0, {top:g}{']' if closed else ')'}")
        return v

    return convert
