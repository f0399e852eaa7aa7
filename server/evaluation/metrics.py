"""Per-episode metrics of the paper's Tables I-III, computed from an episode log.

Success, final position error and orientation error (paper Eq. 33) between two frames, number of
collisions (contact onsets), completion time (simulated seconds), wall time and mean planner rate.
Which frames is the scenario's ``metrics:`` section (:class:`shared.scenario.MetricsConfig`).
A scenario with perceived objects adds the contacts with them and the closest approach to them
(:mod:`server.evaluation.clearance`).
Kinematics are recomputed by replaying logged states into the scenario's model
(:mod:`server.evaluation.replay`), so the same function serves the server's summary, ``m3p2i bench``
and any log on disk. The maths are the small pure functions at the top.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from server.evaluation import log_reader
from server.evaluation.clearance import DIST_MAX, PerceivedClearance
from server.evaluation.replay import load_step, replay, resolve_frame
from shared.config import ErrorLog
from shared.frames import Frame
from shared.geometry import select_axes, symmetric_orientation_error
from shared.scenario import Scenario
from shared.scene import compile_model
from shared.timed_plan import mean_hz


@dataclass(frozen=True)
class EpisodeMetrics:
    """One episode's figures; a metric the scenario does not configure is None."""

    status: str  # success | timeout | stopped | unfinished (log cut short)
    success: bool
    position_error: float | None  # m, metrics.position's a to b (+ offset) at the end
    orientation_error: (
        float | None
    )  # paper Eq. 33 phi between metrics.orientation's frames at the end
    collisions: int | None  # contact onsets between metrics.collisions' bodies
    time: float  # simulated seconds until the episode ended
    wall_time: float  # wall seconds from the planner's handshake to the last step
    planner_hz: float  # 1 / mean planning time of the commands that drove the steps
    steps: int
    # with perceived objects: contact onsets of the robot (and the free objects) with them, and
    # the smallest signed distance to them, m (server.evaluation.clearance)
    perceived_contacts: int | None = None
    perceived_clearance_min: float | None = None

    def as_dict(self) -> dict:
        """Every field; the perceived ones only where measured (a summary of a scenario
        without perceived objects keeps the keys it always had)."""
        out = asdict(self)
        for key in ("perceived_contacts", "perceived_clearance_min"):
            if out[key] is None:
                del out[key]
        return out


# ---------------------------------------------------------------------------------------- maths


def position_error(pos_a: np.ndarray, pos_b: np.ndarray, axes: str = "xyz") -> float:
    """Euclidean distance between two positions along ``axes`` (``xy``, ``xz``, ``yz``, ``xyz``)."""
    d = np.asarray(pos_a, dtype=float) - np.asarray(pos_b, dtype=float)
    return float(np.linalg.norm(select_axes(d, axes)))


def orientation_error(rot_a: np.ndarray, rot_b: np.ndarray) -> float:
    """paper Eq. 33's phi between rotation matrices (symmetric-object metric, 0 = equivalent)."""
    return float(
        symmetric_orientation_error(np.asarray(rot_a, dtype=float), np.asarray(rot_b, dtype=float))
    )


def contact_onsets(touching: Sequence[bool]) -> int:
    """Number of collisions in a per-step contact sequence: each run of consecutive touching
    steps is one collision (a contact held for a second is not twenty collisions)."""
    count, before = 0, False
    for now in touching:
        count += bool(now) and not before
        before = bool(now)
    return count


def wall_time(records: list[dict]) -> float:
    """Wall seconds from the planner's first handshake (or the log's start) to the last step."""
    steps = log_reader.steps(records)
    if not steps:
        return 0.0
    start = next(
        (r["wall"] for r in records if r.get("what") == "handshake"),
        log_reader.header(records).get("wall", steps[0]["wall"]),
    )
    return max(0.0, float(steps[-1]["wall"] - start))


# ------------------------------------------------------------------------------------ evaluator


class MetricsEvaluator:
    """A scenario's metrics bound to its compiled model: frame names are resolved once, here, so
    a wrong name fails when a server starts, not when its episode ends."""

    def __init__(self, scenario: Scenario, model: mujoco.MjModel | None = None):
        self.scenario = scenario
        self.model = model if model is not None else compile_model(scenario)
        cfg = scenario.metrics
        errors = ErrorLog()  # every wrong frame name at once
        self.position = self.orientation = None
        if cfg.position:
            self.position = self._frames(cfg.position, "metrics.position", errors)
        if cfg.orientation:
            self.orientation = self._frames(cfg.orientation, "metrics.orientation", errors)
        self._geoms_a = self._geoms_b = None
        if cfg.collisions:
            self._geoms_a = errors.call(self._geom_mask, cfg.collisions.a, "metrics.collisions.a")
            self._geoms_b = errors.call(
                self._geom_mask, cfg.collisions.with_, "metrics.collisions.with"
            )
        errors.raise_if_any()
        self.perceived = None
        if any(o.perceived for o in scenario.world.objects):
            robot = self._geom_mask(["robot"], "robot")
            self.perceived = PerceivedClearance(scenario, self.model, robot)

    def _frames(self, pair, key: str, errors: ErrorLog) -> tuple[Frame, Frame] | None:
        a = errors.call(resolve_frame, self.scenario, self.model, pair.a, f"{key}.a")
        b = errors.call(resolve_frame, self.scenario, self.model, pair.b, f"{key}.b")
        return (a, b) if a is not None and b is not None else None

    def evaluate(self, records: list[dict], status: str | None = None) -> EpisodeMetrics:
        """Metrics of a logged episode. ``status`` overrides the log's summary (the server calls
        this before writing its summary); a log without either is ``unfinished``."""
        summary = log_reader.summary(records)
        status = status or (summary["status"] if summary else "unfinished")
        steps = log_reader.steps(records)
        pos_err = ori_err = collisions = None
        contacts, clearance = self._replayed(steps)
        if steps:
            data = mujoco.MjData(self.model)
            load_step(self.model, data, steps[-1])
            if self.position:
                a, b = self.position
                pair = self.scenario.metrics.position
                pos_err = position_error(a.pos(data), b.pos(data) + pair.offset, pair.axes)
            if self.orientation:
                a, b = self.orientation
                ori_err = orientation_error(a.rot(data), b.rot(data))
        if self._geoms_a is not None:
            collisions = contact_onsets(contacts)
        return EpisodeMetrics(
            status=status,
            success=status == "success",
            position_error=pos_err,
            orientation_error=ori_err,
            collisions=collisions,
            time=float(steps[-1]["time"]) if steps else 0.0,
            wall_time=wall_time(records),
            planner_hz=mean_hz([s.get("plan_time", 0.0) for s in steps]),
            steps=len(steps),
            perceived_contacts=None if clearance is None else contact_onsets(clearance <= 0.0),
            perceived_clearance_min=(
                None if clearance is None else float(np.min(clearance, initial=DIST_MAX))
            ),
        )

    def _replayed(self, steps: list[dict]) -> tuple[list[bool], np.ndarray | None]:
        """Per logged step, in one replay: whether the ``metrics.collisions`` bodies touch,
        and the clearance to the perceived objects ``[steps]`` (None without any)."""
        touching, clearance = [], []
        if self._geoms_a is not None or self.perceived is not None:
            for data in replay(self.model, steps):
                if self._geoms_a is not None:
                    touching.append(self.touching(data))
                if self.perceived is not None:
                    clearance.append(self.perceived.clearance(data))
        return touching, None if self.perceived is None else np.array(clearance)

    def touching(self, data: mujoco.MjData) -> bool:
        """Whether any contact (penetration or touch, not the collision margin) joins a geom of
        the ``a`` bodies to a geom of the ``with`` bodies."""
        if data.ncon == 0:
            return False
        geom = data.contact.geom
        hit = data.contact.dist <= 0.0
        g1, g2 = geom[:, 0], geom[:, 1]
        pair = (self._geoms_a[g1] & self._geoms_b[g2]) | (self._geoms_a[g2] & self._geoms_b[g1])
        return bool(np.any(pair & hit))

    def _geom_mask(self, names: Sequence[str], key: str) -> np.ndarray:
        """Boolean mask over geoms of the named bodies' subtrees (``robot``: the whole robot)."""
        m = self.model
        mask = np.zeros(m.ngeom, dtype=bool)
        robot_frame = self.scenario.robot.spec.frame
        for i, name in enumerate(names):
            frame = resolve_frame(self.scenario, m, name, f"{key}[{i}]")
            body = (
                frame.id if frame.kind == mujoco.mjtObj.mjOBJ_BODY else int(m.site_bodyid[frame.id])
            )
            if name == "robot" or name == robot_frame:
                body = int(m.body_rootid[body])
            mask |= np.isin(m.geom_bodyid, _subtree(m, body))
        return mask


def _subtree(model: mujoco.MjModel, root: int) -> list[int]:
    """``root`` and every body below it."""
    bodies = []
    for b in range(model.nbody):
        walk = b
        while walk != root and walk != 0:
            walk = int(model.body_parentid[walk])
        if walk == root:
            bodies.append(b)
    return bodies


def describe(m: EpisodeMetrics) -> str:
    """One line for logs and terminals."""
    parts = [m.status]
    if m.position_error is not None:
        parts.append(f"position error {m.position_error:.4f} m")
    if m.orientation_error is not None:
        parts.append(f"orientation error {m.orientation_error:.4f}")
    if m.collisions is not None:
        parts.append(f"collisions {m.collisions}")
    if m.perceived_contacts is not None:
        parts.append(
            f"perceived contacts {m.perceived_contacts}, closest {m.perceived_clearance_min:.3f} m"
        )
    parts += [f"time {m.time:.2f} s", f"wall {m.wall_time:.1f} s", f"planner {m.planner_hz:.1f} Hz"]
    return ", ".join(parts)
