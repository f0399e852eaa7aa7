"""The live page: the world's states and the planner's diagnostics as they come, and the
controls (pause, resume, reset, move) sent to the world."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from pathlib import Path

import mujoco
import numpy as np
import zmq

from m3p2i.view.drawing import PANEL_HZ, PATH_STEP, SCENE_HZ, PanelInfo, SceneDrawing, robot_frame
from m3p2i.view.page import viser_server
from m3p2i.view.perception import (
    RECORD_PERIOD,
    PerceptionDrawing,
    field_record,
    scan_points,
    scan_record,
)
from planner_client.keys import PlannerKeys, curve_client
from planner_client.perception.field_message import FIELD_TOPIC, FieldSlice, decode_field
from server.episode import Published
from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.scans import Scan
from shared.scenario import Scenario
from shared.scene import compile_model, initial_data, set_state

log = logging.getLogger("m3p2i.view")

_DRAIN = 256  # states read at most per poll where their scans matter (the newest is drawn)


class ControlClient:
    """Sends ``control`` ops to the world's control socket, a fresh REQ each time (so a world
    that restarted or does not answer never wedges the view); returns the reply's text."""

    def __init__(
        self,
        ctx: zmq.Context,
        endpoints: Endpoints,
        timeout: float = 2.0,
        keys: PlannerKeys | None = None,
    ):
        self.ctx, self.endpoints, self.timeout, self.keys = ctx, endpoints, timeout, keys
        self._lock = threading.Lock()

    def send(self, msg: P.Control) -> tuple[bool, str]:
        """(accepted, what happened)."""
        with self._lock:
            req = socket(self.ctx, zmq.REQ)
            if self.keys is not None:  # CURVE: the planner's pair, checking the world's key
                curve_client(req, self.keys.own, self.keys.world)
            try:
                req.connect(self.endpoints.control)
                req.send(P.encode(msg))
                if not req.poll(int(self.timeout * 1000)):
                    return False, f"{msg.op}: the world did not answer within {self.timeout:.0f} s"
                reply = P.decode(req.recv(), expect=("control", "error"))
            except P.ProtocolError as exc:
                return False, f"{msg.op}: {exc}"
            finally:
                req.close(0)
        if isinstance(reply, P.Error):
            return False, reply.reason
        return True, f"{msg.op}: done"


class DiagnosticsLog:
    """Appends the planner's diagnostics to a JSON-lines file for the replay, at most ``hz``
    messages per wall second (the replay draws trajectories, it does not need every one);
    and, with a ``kind``, the planner's fields as they come (2 Hz at most) and each sensor's
    points every :data:`RECORD_PERIOD` world seconds (m3p2i.view.perception)."""

    def __init__(self, path: Path, hz: float = 20.0):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = self.path.open("w", buffering=1)
        self._period = 1.0 / hz
        self._last = -np.inf
        self._scan_times: dict[str, float] = {}

    def write(self, msg: P.Diagnostics) -> None:
        now = time.monotonic()
        if now - self._last < self._period:
            return
        self._last = now
        self._f.write(json.dumps(diagnostics_record(msg)) + "\n")

    def write_scan(self, name: str, time: float, points: np.ndarray) -> None:
        """A sensor's points, unless one of its was recorded less than
        :data:`RECORD_PERIOD` world seconds before (an episode reset starts afresh)."""
        if 0 <= time - self._scan_times.get(name, -np.inf) < RECORD_PERIOD:
            return
        self._scan_times[name] = time
        self._f.write(json.dumps(scan_record(name, time, points)) + "\n")

    def write_field(self, fs: FieldSlice) -> None:
        self._f.write(json.dumps(field_record(fs)) + "\n")

    def close(self) -> None:
        self._f.close()


def diagnostics_record(msg: P.Diagnostics) -> dict:
    """A diagnostics message as a JSON-able record (what ``diagnostics.jsonl`` holds)."""
    rec = {
        "seq": msg.seq,
        "action": msg.action,
        "alternatives": list(msg.alternatives),
        "mode_names": list(msg.mode_names),
        "mode_weights": np.round(np.asarray(msg.mode_weights, float), 4).tolist(),
        "top": np.round(np.asarray(msg.top, float), 4).tolist(),
        "plan_time": msg.plan_time,
    }
    if msg.top_modes is not None:
        rec["top_modes"] = np.asarray(msg.top_modes, int).tolist()
    if msg.guide is not None:
        rec["guide"] = np.round(np.asarray(msg.guide, float), 4).tolist()
    if msg.model:
        rec["model"] = {k: round(float(v), 4) for k, v in msg.model.items()}
    return rec


class LiveView:
    """Draws the running world and planner; serves until :meth:`close` (or ``stop`` is set)."""

    def __init__(
        self,
        scenario: Scenario,
        endpoints: Endpoints,
        host: str,
        port: int,
        record: Path | None = None,
        keys: PlannerKeys | None = None,
        controls: bool = True,
    ):
        self.scenario = scenario
        self.model = compile_model(scenario)
        self.data = initial_data(scenario, self.model)
        # a state carries these rows: perceived objects stay where the file puts them
        self._rows = Published.of(scenario, self.model)
        self.robot = robot_frame(scenario, self.model)
        self.controls = controls  # False: the page only shows (pause, reset, move: none)
        self.server = viser_server(host, port, f"m3p2i {scenario.name}")
        self.drawing = SceneDrawing(self.server, self.model, self.data)
        self.info = PanelInfo(scenario=scenario.name)
        sensors = [s.name for s in scenario.sensors]
        self.perception = (
            PerceptionDrawing(self.server, sensors, self.drawing.scale) if sensors else None
        )
        self._scans: dict[str, Scan] = {}  # each sensor's newest reading, not yet drawn
        self._scan_times: dict[str, float] = {}
        self.ctx = zmq.Context()
        # with sensors, every state is read: a reading travels in one state only (or in one
        # re-published lock-step state), and the newest state seldom carries one
        self.state_sub = socket(self.ctx, zmq.SUB, conflate=not sensors)
        self.state_sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.diag_sub = socket(self.ctx, zmq.SUB, conflate=True)
        self.diag_sub.setsockopt(zmq.SUBSCRIBE, b"")
        # the planner makes its map's fields only for a subscriber of their topic
        self.field_sub = socket(self.ctx, zmq.SUB, conflate=True) if sensors else None
        subs = [s for s in (self.diag_sub, self.field_sub) if s is not None]
        if self.field_sub is not None:
            self.field_sub.setsockopt(zmq.SUBSCRIBE, FIELD_TOPIC)
        if keys is not None:
            # CURVE, as a tool beside the planner: the planner's pair; the world's key checked
            # on the state socket, the planner's own on its diagnostics socket
            curve_client(self.state_sub, keys.own, keys.world)
            for sub in subs:
                curve_client(sub, keys.own, keys.own.public)
        self.state_sub.connect(endpoints.state)
        for sub in subs:
            sub.connect(endpoints.diagnostics)
        # a team's other planners publish theirs one port on each (planner_client.loop)
        self.team_subs = [socket(self.ctx, zmq.SUB, conflate=True) for _ in scenario.team[1:]]
        for i, sub in enumerate(self.team_subs, start=1):
            sub.setsockopt(zmq.SUBSCRIBE, b"")
            if keys is not None:
                curve_client(sub, keys.own, keys.own.public)
            sub.connect(Endpoints(endpoints.host, endpoints.port + i).diagnostics)
        self._team_top: dict[int, P.Diagnostics] = {}  # each robot's newest, for the drawing
        self.control = ControlClient(self.ctx, endpoints, keys=keys)
        self.record = DiagnosticsLog(record) if record else None
        self._path: list[np.ndarray] = []
        self._session = ""
        self._diag_times: deque[float] = deque(maxlen=20)
        self._build_gui()
        self.stop = threading.Event()

    @property
    def url(self) -> str:
        host = self.server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{host}:{self.server.get_port()}/"

    def _build_gui(self) -> None:
        gui = self.server.gui
        self.panel = gui.add_markdown(self.info.markdown())
        self.buttons, self.gizmos = {}, {}
        if self.perception is not None:
            self.perception.add_toggles(gui)
        if not self.controls:
            gui.add_markdown("*controls off* (a `--public` view without `--public-controls`)")
            return
        pause = gui.add_button("Pause")
        resume = gui.add_button("Resume")
        reset = gui.add_button("Reset")
        pause.on_click(lambda _: self._send(P.Control(op="pause")))
        resume.on_click(lambda _: self._send(P.Control(op="resume")))
        reset.on_click(lambda _: self._reset())
        self.buttons = {"Pause": pause, "Resume": resume, "Reset": reset}
        movable = gui.add_checkbox(
            "move objects",
            False,
            hint="Show a handle on each object: "
            "drag it to move the object; the world logs a disturbance.",
        )
        mj_data = self.data
        for obj in self.scenario.world.objects:
            body = self.model.body(obj.name)
            # big enough to grab on a 5 cm cube, small enough not to hide a table
            size = float(np.clip(np.max(obj.size) * 3.0, 0.08, 0.5))
            g = self.server.scene.add_transform_controls(
                f"/drag/{obj.name}",
                scale=size,
                disable_sliders=True,
                depth_test=False,
                position=mj_data.xpos[body.id],
                wxyz=mj_data.xquat[body.id],
                visible=False,
            )
            g.dragging = False
            g.on_update(lambda event, name=obj.name: self._dragged(name, event))
            self.gizmos[obj.name] = (body.id, g)

        def show_handles(_) -> None:
            for _, g in self.gizmos.values():
                g.visible = movable.value

        movable.on_update(show_handles)

    def _send(self, msg: P.Control) -> bool:
        if not self.controls:
            log.warning("control %s not sent: this view's controls are off", msg.op)
            return False
        ok, text = self.control.send(msg)
        self.info.note = text if ok else f"**refused**: {text}"
        log.info("control %s: %s", msg.op, text)
        return ok

    def _reset(self) -> None:
        if self._send(P.Control(op="reset")):
            self._path.clear()
            self.drawing.set_path(np.zeros((0, 3)))

    def _dragged(self, name: str, event) -> None:
        """A handle's drag: the state no longer moves it from ``start`` on; at ``end`` the
        object is moved where it was let go."""
        gizmo = event.target
        gizmo.dragging = event.phase != "end"
        if event.phase != "end":
            return
        self._send(
            P.Control(
                op="move",
                object=name,
                pos=np.asarray(gizmo.position, float),
                quat=np.asarray(gizmo.wxyz, float),
            )
        )

    def serve(self, duration: float | None = None) -> None:
        """Receive and draw until ``stop`` is set (or ``duration`` seconds passed)."""
        poller = zmq.Poller()
        poller.register(self.state_sub, zmq.POLLIN)
        poller.register(self.diag_sub, zmq.POLLIN)
        for sub in self.team_subs:
            poller.register(sub, zmq.POLLIN)
        if self.field_sub is not None:
            poller.register(self.field_sub, zmq.POLLIN)
        end = None if duration is None else time.monotonic() + duration
        last_scene = last_panel = 0.0
        state = diag = None
        while not self.stop.is_set() and (end is None or time.monotonic() < end):
            events = dict(poller.poll(20))
            if self.state_sub in events:
                state = self._states() or state
            if self.field_sub is not None and self.field_sub in events:
                self._field(self.field_sub.recv())
            for i, sub in enumerate([self.diag_sub, *self.team_subs]):
                got = self._receive(sub, "diagnostics") if sub in events else None
                if got is not None:
                    diag = self._team_top[i] = got
                    self._diagnostics(got)
            now = time.monotonic()
            if state is not None and now - last_scene >= 1 / SCENE_HZ:
                self._state(state)
                self._draw_scans()
                if diag is not None:
                    self.drawing.set_top(*self._tops(diag))
                    self.drawing.set_guide(diag.guide)
                    diag = None
                state = None
                last_scene = now
            if now - last_panel >= 1 / PANEL_HZ:
                self.panel.content = self.info.markdown()
                last_panel = now

    def _receive(self, sock, kind: str, frame: bytes | None = None):
        frame = sock.recv() if frame is None else frame
        if frame.startswith(FIELD_TOPIC):  # a field on the diagnostics' socket: field_sub's
            return None
        try:
            return P.decode(frame, expect=kind)
        except P.ProtocolError as exc:
            log.warning("ignored a %s message: %s", kind, exc)
            return None

    def _states(self) -> P.State | None:
        """The newest waiting state, each sensor's newest reading kept from all of them."""
        state = None
        for _ in range(_DRAIN):
            try:
                frame = self.state_sub.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            got = self._receive(self.state_sub, "state", frame)
            if got is None:
                continue
            state = got
            for scan in got.scans:  # a re-published state repeats its readings
                if scan.time != self._scan_times.get(scan.name):
                    self._scan_times[scan.name] = scan.time
                    self._scans[scan.name] = scan
        return state

    def _draw_scans(self) -> None:
        if self.perception is None or not self._scans:
            return
        points = {name: scan_points(scan) for name, scan in self._scans.items()}
        self.perception.set_scans(points)
        if self.record is not None:
            for name, scan in self._scans.items():
                self.record.write_scan(name, scan.time, points[name])
        self._scans.clear()

    def _field(self, frame: bytes) -> None:
        try:
            fs = decode_field(frame)
        except P.ProtocolError as exc:
            log.warning("ignored a field message: %s", exc)
            return
        self.perception.set_field(fs)
        if self.record is not None:
            self.record.write_field(fs)

    def _state(self, state: P.State) -> None:
        values = vars(state)
        try:
            if self._rows is not None:
                values = {**values, **self._rows.into(self.data, state)}
            set_state(self.model, self.data, values)
        except ValueError as exc:
            self.info.note = (
                f"**the world's state does not fit {self.scenario.name}'s model** "
                f"({exc}): is the view attached to the right scenario?"
            )
            return
        mujoco.mj_kinematics(self.model, self.data)
        if state.session != self._session or (self._path and state.time < self._last_time):
            self._path.clear()  # a new world, or a reset: a new path
        self._session, self._last_time = state.session, state.time
        p = self.robot.pos(self.data).copy()
        if not self._path or np.linalg.norm(p - self._path[-1]) > PATH_STEP:
            self._path.append(p)
            self.drawing.set_path(np.array(self._path))
        self.drawing.set_poses(self.data)
        for body, g in self.gizmos.values():
            if not g.dragging:
                g.position = self.data.xpos[body].copy()
                g.wxyz = self.data.xquat[body].copy()
        self.info.status, self.info.time, self.info.extras = state.status, state.time, state.extras

    def _tops(self, diag: P.Diagnostics) -> tuple[np.ndarray, np.ndarray | None]:
        """The best trajectories to draw: the planner's, or every team robot's newest, each
        robot in its own colour."""
        if not self.team_subs:
            return diag.top, diag.top_modes
        tops = list(self._team_top.items())
        return (
            np.concatenate([d.top for _, d in tops]),
            np.concatenate([np.full(len(d.top), i) for i, d in tops]),
        )

    def _diagnostics(self, d: P.Diagnostics) -> None:
        now = time.monotonic()
        self._diag_times.append(now)
        if len(self._diag_times) > 1:
            span = self._diag_times[-1] - self._diag_times[0]
            self.info.planner_hz = (len(self._diag_times) - 1) / span if span > 0 else None
        self.info.plan_ms = d.plan_time * 1000
        self.info.samples = d.samples
        # the best trajectories [M, T, 3] are as long as the plan: its steps under a budget
        self.info.horizon = None if d.samples is None else int(d.top.shape[1])
        self.info.action, self.info.alternatives = d.action, list(d.alternatives)
        total = float(np.sum(d.mode_weights)) or 1.0
        self.info.mode_names = list(d.mode_names)
        self.info.mode_weights = [float(w) / total for w in d.mode_weights]
        self.info.model = dict(d.model or {})
        if self.record is not None:
            self.record.write(d)

    def close(self, keep_server: bool = False) -> None:
        """Stop receiving (and recording); with ``keep_server`` the page stays served, for a
        :class:`ReplayView` to take over (``m3p2i run --view`` once its episode is over)."""
        self.stop.set()
        if not self.ctx.closed:
            for s in (self.state_sub, self.diag_sub, self.field_sub, *self.team_subs):
                if s is not None:
                    s.close(0)
            self.ctx.term()
            if self.record is not None:
                self.record.close()
        if not keep_server:
            self.server.stop()
