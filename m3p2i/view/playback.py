"""The replay page: an episode log (and its recorded diagnostics) with a time slider, the
actions and the metrics."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from m3p2i.view.drawing import PanelInfo, SceneDrawing, robot_frame
from m3p2i.view.page import viser_server
from m3p2i.view.perception import PerceptionDrawing, PerceptionTrack
from server.evaluation import log_reader
from shared.scenario import Scenario
from shared.scene import compile_model, initial_data


@dataclass
class Replay:
    """An episode log ready to draw: its step records, action changes, metrics and, when
    recorded, the planner's diagnostics by state seq and the scans and fields the view
    recorded (m3p2i.view.perception)."""

    scenario: Scenario
    steps: list[dict]
    actions: list[tuple[float, str]]
    summary: dict | None
    diagnostics: dict[int, dict]
    disturbances: list[dict]
    perception: PerceptionTrack = field(default_factory=PerceptionTrack)

    @property
    def times(self) -> np.ndarray:
        return np.array([s["time"] for s in self.steps])

    def diagnostics_at(self, seq: int) -> dict | None:
        """The newest recorded diagnostics for a state at or before ``seq``."""
        if not self.diagnostics:
            return None
        keys = self._keys
        i = int(np.searchsorted(keys, seq, side="right")) - 1
        return self.diagnostics[int(keys[i])] if i >= 0 else None

    def __post_init__(self):
        self._keys = np.array(sorted(self.diagnostics), dtype=int)


def load_replay(log_path: Path, scenario: str | None = None) -> Replay:
    """Read an episode log (a file or run folder) and the ``diagnostics.jsonl`` beside it."""
    path = log_reader.find_log(log_path)
    records = log_reader.read_log(path)
    sc = log_reader.log_scenario(records, scenario)
    steps = log_reader.steps(records)
    if not steps:
        raise ValueError(f"{path}: no step records to replay (the episode never started)")
    summary = log_reader.summary(records)
    actions = [
        (float(r["time"]), r["action"])
        for r in records
        if r.get("kind") == "event" and r.get("what") == "action"
    ]
    disturbances = [
        r for r in records if r.get("kind") == "event" and r.get("what") == "disturbance"
    ]
    diag_path = path.parent / "diagnostics.jsonl"
    recorded = log_reader.read_log(diag_path) if diag_path.is_file() else []
    diags = {int(r["seq"]): r for r in recorded if "kind" not in r}
    track = PerceptionTrack.of([r for r in recorded if "kind" in r])
    return Replay(sc, steps, actions, summary, diags, disturbances, track)


def action_timeline(actions: list[tuple[float, str]], now: float) -> str:
    """The episode's actions as markdown lines, the one running at ``now`` in bold."""
    lines = []
    current = max((i for i, (t, _) in enumerate(actions) if t <= now + 1e-9), default=-1)
    for i, (t, a) in enumerate(actions):
        text = f"{t:6.2f} s `{a or '—'}`"
        lines.append(f"**▶ {text}**  " if i == current else f"{text}  ")
    return "\n".join(lines) or "(no actions logged)"


def metrics_text(summary: dict | None) -> str:
    """The episode's outcome and metrics (paper Tables I-III: errors, collisions, time) as
    markdown; the success test's measures where the log has no metrics."""
    if summary is None:
        return "**no summary**: the log ends before the episode did"
    parts = [f"**outcome**: {summary.get('status')} at {summary.get('time', 0):.2f} s"]
    metrics = {
        k: v
        for k, v in (summary.get("metrics") or {}).items()
        if isinstance(v, (int, float))
        and not isinstance(v, bool)
        and k not in ("time", "wall_time", "planner_hz", "steps")
    }
    for k, v in (metrics or summary.get("measures") or {}).items():
        parts.append(f"{k.replace('_', ' ')}: {v:.4g}")
    if summary.get("planner_hz"):
        parts.append(f"planner: {summary['planner_hz']:.1f} Hz")
    return "  \n".join(parts)


class ReplayView:
    """Plays an episode log with a time slider, the same drawing as live."""

    def __init__(self, replay: Replay, host: str, port: int, server=None):
        """``server``: a page already served (a live view's, whose episode is over): its scene
        and panel are replaced by the replay's, and a browser showing it stays connected."""
        self.replay = replay
        sc = replay.scenario
        self.model = compile_model(sc)
        self.data = initial_data(sc, self.model)
        self.robot = robot_frame(sc, self.model)
        if server is not None:
            server.scene.reset()
            server.gui.reset()
        self.server = server or viser_server(host, port, f"m3p2i replay {sc.name}")
        self.drawing = SceneDrawing(self.server, self.model, self.data)
        sensors = [s.name for s in sc.sensors]
        self.perception = (
            PerceptionDrawing(self.server, sensors, self.drawing.scale) if sensors else None
        )
        self.path = self._robot_path()
        times = replay.times
        self.stop = threading.Event()
        gui = self.server.gui
        self.panel = gui.add_markdown("")
        if self.perception is not None:
            self.perception.add_toggles(gui)
        self.slider = gui.add_slider(
            "time [s]",
            min=float(times[0]),
            max=float(times[-1]),
            step=float(self.model.opt.timestep),
            initial_value=float(times[-1]),
        )
        self.play = gui.add_checkbox("play", False)
        self.speed = gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
        gui.add_markdown("**actions**")
        self.timeline = gui.add_markdown("")
        gui.add_markdown(metrics_text(replay.summary))
        self.slider.on_update(lambda _: self.show(self.slider.value))
        self.show(float(times[-1]))

    @property
    def url(self) -> str:
        host = self.server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{host}:{self.server.get_port()}/"

    def _robot_path(self) -> np.ndarray:
        data = mujoco.MjData(self.model)
        out = np.empty((len(self.replay.steps), 3))
        for i, step in enumerate(self.replay.steps):
            _load(self.model, data, step)
            out[i] = self.robot.pos(data)
        return out

    def index_at(self, t: float) -> int:
        return max(
            0,
            min(
                int(np.searchsorted(self.replay.times, t + 1e-9, side="right")) - 1,
                len(self.replay.steps) - 1,
            ),
        )

    def show(self, t: float) -> None:
        """Draw the logged state at time ``t``: poses, path so far, trajectories, panel."""
        i = self.index_at(t)
        step = self.replay.steps[i]
        _load(self.model, self.data, step)
        self.drawing.set_poses(self.data)
        self.drawing.set_path(self.path[: i + 1])
        d = self.replay.diagnostics_at(int(step["seq"]))
        self.drawing.set_top(
            None if d is None else np.asarray(d["top"]),
            None if d is None or "top_modes" not in d else np.asarray(d["top_modes"]),
        )
        self.drawing.set_guide(None if d is None or "guide" not in d else np.asarray(d["guide"]))
        if self.perception is not None:
            self.perception.set_scans(self.replay.perception.scans_at(float(step["time"])))
            self.perception.set_field(self.replay.perception.field_at(float(step["time"])))
        info = PanelInfo(
            scenario=self.replay.scenario.name,
            time=float(step["time"]),
            status=f"replay, step {i + 1} of {len(self.replay.steps)}",
            action=step.get("action", ""),
            extras=step.get("extras") or {},
            samples=step.get("samples"),
            horizon=step.get("horizon"),
        )
        if d is not None:
            total = float(np.sum(d["mode_weights"])) or 1.0
            info.alternatives = d.get("alternatives", [])
            info.mode_names = d.get("mode_names", [])
            info.mode_weights = [w / total for w in d["mode_weights"]]
            info.plan_ms = d["plan_time"] * 1000
            info.planner_hz = 1.0 / d["plan_time"] if d["plan_time"] > 0 else None
            info.model = d.get("model", {})
        elif not self.replay.diagnostics:
            info.note = "(no diagnostics.jsonl beside the log: no sampled trajectories to show)"
        if self.perception is not None and not self.replay.perception:
            note = "(no scans or map recorded: the run had no --view)"
            info.note = f"{info.note} {note}" if info.note else note
        self.panel.content = info.markdown()
        self.timeline.content = action_timeline(self.replay.actions, float(step["time"]))

    def serve(self, duration: float | None = None) -> None:
        """Advance the slider while ``play`` is ticked, until stopped."""
        end = None if duration is None else time.monotonic() + duration
        last = time.monotonic()
        while not self.stop.is_set() and (end is None or time.monotonic() < end):
            time.sleep(1 / 20)
            now = time.monotonic()
            if self.play.value:
                t = self.slider.value + (now - last) * self.speed.value
                if t >= self.slider.max:
                    t = self.slider.min  # loop
                self.slider.value = t  # on_update draws it
            last = now

    def close(self) -> None:
        self.stop.set()
        self.server.stop()


def _load(model: mujoco.MjModel, data: mujoco.MjData, step: dict) -> None:
    from server.evaluation.replay import load_step

    load_step(model, data, step)
