"""The planner's map kept up to date beside it: :class:`MapUpdater` owns an occupancy map
(:class:`OccupancyGrid2D` for a base's lidar, :class:`VoxelGrid` for a depth camera over an
arm's workspace), fuses the scans it is given, turns the map into a signed distance field
composed with the known geometry, and publishes it.

The controller hands it each state's scans with :meth:`MapUpdater.submit`, from the network
loop: that only queues them, each with the spheres its ``self_filter`` reads from the state's
mirrored scene then (:mod:`planner_client.perception.self_filter`: the robot and what the
planner models, not fused as obstacles). Where they are fused depends on the mode, as for the guide
(:mod:`planner_client.guide`):

- **real time** (``threaded=True``): a thread of its own fuses whatever is queued and
  recomputes the field at most ``cfg.rate_hz`` times a second; an iteration never waits for it
  and reads :meth:`MapUpdater.latest`, the newest field, replaced whole (an atomic reference
  swap: a reader holds one consistent field however long its rollouts take).
- **lock-step** (``threaded=False``): no thread. The controller calls
  :meth:`MapUpdater.update_now` at a fixed point of its loop (e.g. at each state that brought
  new scans, before the iteration plans), which fuses everything queued and recomputes the field
  there. What the planner reads then depends on the states alone, never on how fast a thread ran,
  so an episode stays the same for its seed.

:meth:`MapUpdater.stats` reports the update's cost and rate for the benchmark and diagnostics;
:meth:`MapUpdater.close` stops the thread (and is harmless in lock-step).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from planner_client.perception.field import DistanceField
from planner_client.perception.occupancy import OccupancyMap
from planner_client.perception.sdf import compose, distance_field
from shared.scans import Scan

log = logging.getLogger(__name__)

_RATE_WINDOW = 20  # fields whose publication times give the measured rate


class MapUpdater:
    """Fuses scans into ``occupancy`` and publishes its signed distance field, composed with
    ``known`` (a field on the same grid: the declared walls and objects) when given (module
    docstring). ``sensors``: the names of the sensors it reads (all the map accepts when None).
    ``self_filter``: the spheres ``[n, 4]`` (centre, radius, m) that a state's mirrored scene
    holds what the planner models in, cut out of the scans that came with it (None: none).
    """

    def __init__(
        self,
        occupancy: OccupancyMap,
        known: DistanceField | None = None,
        sensors: Iterable[str] | None = None,
        threaded: bool = False,
        self_filter: Callable[[Any], np.ndarray] | None = None,
    ):
        spec = occupancy.spec
        if known is not None and (
            tuple(known.values.shape) != spec.shape
            or tuple(known.origin) != tuple(spec.origin)
            or known.resolution != spec.resolution
        ):
            raise ValueError("the known field must lie on the map's grid")
        self.map, self.known, self.cfg = occupancy, known, occupancy.cfg
        self.sensors = None if sensors is None else frozenset(sensors)
        self.self_filter = self_filter
        # each scan with the spheres cut out of it (None: nothing)
        self._queue: collections.deque[tuple[Scan, np.ndarray | None]] = collections.deque()
        self._cv = threading.Condition()
        self._work = threading.Lock()  # one fusion at a time: the thread's or update_now's
        self._field: DistanceField | None = None
        self._dirty = False  # scans fused since the last field
        self._closed = False
        self._counts = {"submitted": 0, "dropped": 0, "ignored": 0, "fields": 0}
        self._times = {"fuse_s": 0.0, "field_s": 0.0, "fuse_total_s": 0.0, "field_total_s": 0.0}
        self._published: collections.deque[float] = collections.deque(maxlen=_RATE_WINDOW)
        self._thread: threading.Thread | None = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="map-updater", daemon=True)
            self._thread.start()

    def submit(self, scans: Iterable[Scan], scene: Any = None) -> None:
        """Queue scans for the map (cheap: the network loop calls it with each state's). The
        oldest are dropped past ``cfg.max_queue``; scans of other sensors or kinds are
        ignored. ``scene``: the planner's mirror of the state they came with (its kinematics
        done), which the self-filter reads now (None: the scans are fused unfiltered)."""
        spheres = None
        if self.self_filter is not None and scene is not None:
            spheres = self.self_filter(scene)
        with self._cv:
            for scan in scans:
                if not self._reads(scan):
                    self._counts["ignored"] += 1
                    continue
                if len(self._queue) >= self.cfg.max_queue:
                    self._queue.popleft()
                    self._counts["dropped"] += 1
                self._queue.append((scan, spheres))
                self._counts["submitted"] += 1
            self._cv.notify_all()

    def latest(self) -> DistanceField | None:
        """The newest published field, or None before the first."""
        return self._field

    def update_now(self) -> DistanceField | None:
        """Fuse every queued scan and publish a new field now, whatever the rate (lock-step:
        call it at a fixed point of the loop). Returns the newest field (None while no map
        and no known geometry exist to make one)."""
        with self._work:
            self._fuse(self._take())
            if self._dirty or (self._field is None and self.known is not None):
                self._publish()
        return self._field

    def stats(self) -> dict[str, float]:
        """The update's figures: scans ``submitted``, ``dropped`` (queue full) and ``ignored``
        (not this map's), ``fused`` into it, ``fields`` published; seconds of the last
        fusion and field computation (``fuse_s``, ``field_s``) and their means per field
        (``update_s``: both together); ``rate_hz``, fields a second over the recent ones."""
        with self._cv:
            out: dict[str, float] = {k: float(v) for k, v in self._counts.items()}
            out.update(self._times)
            published = list(self._published)
        n = max(out["fields"], 1.0)
        out["fused"] = float(self.map.scans)
        out["update_s"] = (out.pop("fuse_total_s") + out.pop("field_total_s")) / n
        span = published[-1] - published[0] if len(published) > 1 else 0.0
        out["rate_hz"] = (len(published) - 1) / span if span > 0 else 0.0
        return out

    def close(self) -> None:
        """Stop the thread (waiting for its current update); queued scans are dropped."""
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            if self._thread.is_alive():
                log.warning("map updater: the thread did not stop within 10 s")

    def _reads(self, scan: Scan) -> bool:
        named = self.sensors is None or scan.name in self.sensors
        return named and self.map.accepts(scan)

    def _take(self) -> list[tuple[Scan, np.ndarray | None]]:
        with self._cv:
            scans = list(self._queue)
            self._queue.clear()
        return scans

    def _fuse(self, scans: list[tuple[Scan, np.ndarray | None]]) -> None:
        if not scans:
            return
        start = time.perf_counter()
        for scan, spheres in scans:
            self.map.insert(scan, spheres)
        spent = time.perf_counter() - start
        with self._cv:
            self._times["fuse_s"] = spent
            self._times["fuse_total_s"] += spent
        self._dirty = True

    def _publish(self) -> None:
        start = time.perf_counter()
        occ = self.map
        field = distance_field(occ.occupied(), occ.spec, occ.time)
        if self.known is not None:
            field = compose(field, self.known)
        spent = time.perf_counter() - start
        self._field = field  # the swap: readers see the old field or this one, whole
        self._dirty = False
        with self._cv:
            self._times["field_s"] = spent
            self._times["field_total_s"] += spent
            self._counts["fields"] += 1
            self._published.append(time.monotonic())

    def _run(self) -> None:
        period = 1.0 / self.cfg.rate_hz
        due = time.monotonic()  # when the next field may be computed
        while True:
            with self._cv:
                while not self._closed and not self._queue and not self._dirty:
                    self._cv.wait()
                if self._closed:
                    return
            with self._work:
                self._fuse(self._take())
                now = time.monotonic()
                if self._dirty and now >= due:
                    self._publish()
                    due = now + period
            with self._cv:  # too soon for a field: wait for the rate, or for more scans
                wait = due - time.monotonic()
                if self._dirty and wait > 0 and not self._closed:
                    self._cv.wait(timeout=wait)
