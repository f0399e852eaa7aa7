"""``m3p2i view``: the world and the planner in a browser, live or replayed from an episode log.

Live, it is a read-only subscriber: it connects to the world's ``state`` socket and the
planner's ``diagnostics`` socket (PUB/SUB, so the planner never waits for it) and sends only
the ``control`` ops a user asks for (pause, resume, reset, move an object). Replay reads an
episode log (and the ``diagnostics.jsonl`` beside it, when the live view recorded one).

The page is served by viser (the optional extra ``m3p2i[view]``): its web client ships inside
the wheel, so the page loads with no network beyond the machine serving it. The drawing is
:mod:`m3p2i.view_scene` (pure: the model's geoms as meshes, their poses).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import zmq

from m3p2i.view_scene import GeomShape, camera_for, geom_poses, scene_bounds, scene_shapes
from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.evaluation import episode
from shared.frames import FrameResolver
from shared.scenario import Scenario
from shared.scene import compile_model, initial_data, set_state
from shared.security import PlannerKeys, curve_client

log = logging.getLogger("m3p2i.view")

MODE_COLOURS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
]
"""Colour of mode i's sampled trajectories (matplotlib's tab10, which the plots use too)."""
PATH_COLOUR = (20, 20, 20)
_PANEL_HZ = 10.0  # text panel refreshes per second: readable, and cheap for the browser
_SCENE_HZ = 30.0  # pose updates per second sent to the browser at most
_PATH_STEP = 0.005  # m: executed-path points closer than this to the last one are skipped


def import_viser():
    """viser, or an ImportError telling how to install it."""
    try:
        import viser
    except ImportError as exc:
        raise ImportError(
            "the browser view needs viser: pip install 'm3p2i[view]' (or pip install viser)"
        ) from exc
    return viser


# ------------------------------------------------------------------------------ origin check
#
# A browser lets any web page open a websocket to any address, 127.0.0.1 included, and the view's
# websocket carries the scene and the controls (pause, reset, move): an open tab on a hostile
# site could drive the world. viser checks no Origin, so the view refuses (HTTP 403) a websocket
# handshake that announces an Origin other than the page's own: ``http://`` + the Host it was
# asked for, where that host is loopback (127.0.0.1, localhost, ::1) or, for a --public view, an
# IP address or this machine's name. The host rule defeats DNS rebinding (a hostile name that
# resolves to 127.0.0.1 makes its page same-origin with itself). A handshake without an Origin
# is not from a browser page (browsers always send one) and is accepted: a program that can
# reach the port could forge any header, so the check guards browsers, it is no password.

_LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})


@dataclass(frozen=True)
class OriginPolicy:
    """Which pages may open the view's websocket; :meth:`refusal` says why one may not."""

    public: bool = False
    names: frozenset[str] = frozenset()  # with ``public``: this machine's names

    @classmethod
    def for_bind(cls, bind: str) -> OriginPolicy:
        import socket as _socket

        if bind in ("127.0.0.1", "localhost", "::1"):
            return cls()
        names = {_socket.gethostname(), _socket.getfqdn(), bind}
        return cls(public=True, names=frozenset(n.lower() for n in names if n))

    def refusal(self, origin: str | None, host: str | None) -> str | None:
        if origin is None:
            return None
        if not host or origin.lower() != f"http://{host.lower()}":
            return f"origin {origin!r} is not this page's (http://{host})"
        name = host.lower().rsplit(":", 1)[0] if not host.endswith("]") else host.lower()
        name = name.strip("[]")
        if name in _LOOPBACK_NAMES:
            return None
        if self.public and (name in self.names or _is_ip(name)):
            return None
        return f"host {name!r} is not loopback" + (
            "" if not self.public else ", an IP address or this machine's name"
        )


def _is_ip(name: str) -> bool:
    import ipaddress

    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


_guard_lock = threading.Lock()
_guard_next: OriginPolicy | None = None  # the policy of the ViserServer being constructed
_guard_applied = False


class _Proxy:
    """A module with some attributes replaced (the rest read from the real one)."""

    def __init__(self, real, **override):
        self._real, self._override = real, override

    def __getattr__(self, name: str):
        return self._override[name] if name in self._override else getattr(self._real, name)


def _install_origin_guard() -> None:
    """Wrap viser's call of websockets' ``serve`` (only viser's: its module's ``websockets`` is
    replaced by a proxy) so that the server it starts checks :data:`_guard_next`'s policy in
    ``process_request``, ahead of viser's own (which serves the page's files)."""
    import http

    try:
        from viser.infra import _infra

        real = _infra.websockets
        serve = real.asyncio.server.serve
    except (ImportError, AttributeError):  # another viser: viser_server says so
        return
    if isinstance(real, _Proxy):
        return

    def guarded_serve(*args, process_request=None, **kwargs):
        global _guard_applied
        policy = _guard_next
        if policy is None:
            return serve(*args, process_request=process_request, **kwargs)

        def check(connection, request):
            if request.headers.get("Upgrade", "").lower() == "websocket":
                origins, hosts = (request.headers.get_all(h) for h in ("Origin", "Host"))
                why = (
                    "several Origin or Host headers"
                    if len(origins) > 1 or len(hosts) != 1
                    else policy.refusal(origins[0] if origins else None, hosts[0])
                )
                if why is not None:
                    log.warning("refused a websocket from %s: %s", connection.remote_address, why)
                    return connection.respond(http.HTTPStatus.FORBIDDEN, f"refused: {why}\n")
            return None if process_request is None else process_request(connection, request)

        _guard_applied = True
        return serve(*args, process_request=check, **kwargs)

    _infra.websockets = _Proxy(
        real, asyncio=_Proxy(real.asyncio, server=_Proxy(real.asyncio.server, serve=guarded_serve))
    )


def viser_server(host: str, port: int, label: str):
    """A started ViserServer whose websocket accepts only its own pages
    (:class:`OriginPolicy`); ImportError when viser is missing or its server cannot be guarded."""
    global _guard_next, _guard_applied
    viser = import_viser()
    with _guard_lock:
        _install_origin_guard()
        _guard_next, _guard_applied = OriginPolicy.for_bind(host), False
        try:
            server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
        finally:
            _guard_next, applied = None, _guard_applied
    if not applied:
        server.stop()
        raise ImportError(
            f"viser {getattr(viser, '__version__', '?')} starts its web server in "
            f"a way m3p2i cannot guard (the websocket's Origin check): use the "
            f"viser version of m3p2i[view]"
        )
    return server


def rgb255(rgba) -> tuple[int, int, int]:
    return tuple(round(255 * min(max(c, 0.0), 1.0)) for c in rgba[:3])


def trajectory_segments(
    top: np.ndarray, top_modes: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Line segments ``[S, 2, 3]`` and their colours ``[S, 2, 3]`` (uint8) of the sampled
    trajectories ``top [M, T, 3]``, each coloured by its mode (``top_modes [M]``; mode 0 when
    the planner did not say)."""
    top = np.asarray(top, float)
    if top.ndim != 3 or top.shape[1] < 2:
        return np.zeros((0, 2, 3)), np.zeros((0, 2, 3), np.uint8)
    modes = np.zeros(len(top), int) if top_modes is None else np.asarray(top_modes, int)
    segs = np.stack([top[:, :-1], top[:, 1:]], axis=2).reshape(-1, 2, 3)
    per_traj = np.array([MODE_COLOURS[m % len(MODE_COLOURS)] for m in modes], np.uint8)
    cols = np.repeat(per_traj, top.shape[1] - 1, axis=0)[:, None, :].repeat(2, axis=1)
    return segs, cols


def path_segments(points: np.ndarray) -> np.ndarray:
    """Consecutive points ``[P, 3]`` as segments ``[P-1, 2, 3]``."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) < 2:
        return np.zeros((0, 2, 3))
    return np.stack([points[:-1], points[1:]], axis=1)


def weight_bar(weight: float, width: int = 20) -> str:
    """A text bar for a mode weight in 0-1 (the panel's bar chart)."""
    w = min(max(float(weight), 0.0), 1.0)
    full = round(w * width)
    return "█" * full + "░" * (width - full)


@dataclass
class PanelInfo:
    """What the side panel shows, from the newest state and diagnostics."""

    scenario: str = ""
    status: str = "waiting for the world"
    time: float = 0.0
    action: str = ""
    alternatives: list[str] = field(default_factory=list)
    mode_names: list[str] = field(default_factory=list)
    mode_weights: list[float] = field(default_factory=list)
    planner_hz: float | None = None
    plan_ms: float | None = None
    extras: dict[str, float] = field(default_factory=dict)
    model: dict[str, float] = field(default_factory=dict)  # identified: "mass.box" -> factor
    note: str = ""

    def markdown(self) -> str:
        lines = [f"**{self.scenario}** — {self.status}, t = {self.time:.2f} s", ""]
        lines.append(f"**action**: `{self.action or '—'}`")
        if self.alternatives:
            lines.append("**alternatives**: " + ", ".join(f"`{a}`" for a in self.alternatives))
        if self.mode_names:
            lines += ["", "**mode weights**", ""]
            for i, (name, w) in enumerate(zip(self.mode_names, self.mode_weights)):
                r, g, b = MODE_COLOURS[i % len(MODE_COLOURS)]
                lines.append(
                    f"<span style='color:rgb({r},{g},{b})'>{weight_bar(w)}</span> "
                    f"{w:.2f} `{name}`  "
                )
        if self.planner_hz is not None:
            lines += [
                "",
                f"**planner**: {self.planner_hz:.1f} Hz"
                + (f", {self.plan_ms:.0f} ms per plan" if self.plan_ms is not None else ""),
            ]
        for k, v in self.extras.items():
            lines.append(f"**{k}**: {v:.1f}")
        if self.model:  # planner.model.variants: the planner's estimate of the world's model
            lines += ["", "**identified model** (× nominal)", ""]
            lines += [f"`{k}` {v:.2f}  " for k, v in sorted(self.model.items())]
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines)


class SceneDrawing:
    """The scenario's model drawn in a viser scene: meshes once, then poses, the planner's
    sampled trajectories and the executed path."""

    def __init__(self, server, model: mujoco.MjModel, data: mujoco.MjData):
        self.server = server
        self.model = model
        self.shapes: list[GeomShape] = scene_shapes(model)
        server.scene.set_up_direction("+z")
        self.handles = {}
        pos, quat = geom_poses(model, data)
        for s in self.shapes:
            self.handles[s.geom_id] = server.scene.add_mesh_simple(
                f"/world/{s.name}",
                s.vertices,
                s.faces,
                color=rgb255(s.rgba),
                opacity=None if s.rgba[3] >= 1 else float(s.rgba[3]),
                side="double" if s.kind == "plane" else "front",
                flat_shading=s.kind == "box",
                wxyz=quat[s.geom_id],
                position=pos[s.geom_id],
            )
        self.moving = [s.geom_id for s in self.shapes if s.movable]
        self._top = None
        self._path = None
        self._guide = None
        lo, hi = scene_bounds(model, data, self.shapes)
        # every new page (and the client's "reset view") starts framing the scene
        position, look_at = camera_for(lo, hi)
        server.initial_camera.position = tuple(position)
        server.initial_camera.look_at = tuple(look_at)
        self.scale = float(np.linalg.norm(hi - lo))
        self._line = max(0.002, 0.0025 * self.scale)

    def set_poses(self, data: mujoco.MjData) -> None:
        pos, quat = geom_poses(self.model, data)
        with self.server.atomic():
            for g in self.moving:
                h = self.handles[g]
                h.position = pos[g]
                h.wxyz = quat[g]

    def set_top(self, top: np.ndarray | None, top_modes: np.ndarray | None) -> None:
        segs, cols = trajectory_segments(top if top is not None else np.zeros((0, 0, 3)), top_modes)
        if self._top is not None:
            self._top.remove()
            self._top = None
        if len(segs):
            self._top = self.server.scene.add_line_segments(
                "/planner/top", segs.astype(np.float32), cols, thickness=self._line
            )

    def set_guide(self, corners: np.ndarray | None) -> None:
        """The scenario guide's path (its corners ``[N, 3]``), or none."""
        segs = path_segments(corners if corners is not None else np.zeros((0, 3)))
        if self._guide is not None:
            self._guide.remove()
            self._guide = None
        if len(segs):
            cols = np.tile(np.array([242, 191, 26], np.uint8), (len(segs), 2, 1))
            self._guide = self.server.scene.add_line_segments(
                "/planner/guide", segs.astype(np.float32), cols, thickness=2 * self._line
            )

    def set_path(self, points: np.ndarray) -> None:
        segs = path_segments(points)
        if self._path is not None:
            self._path.remove()
            self._path = None
        if len(segs):
            self._path = self.server.scene.add_line_segments(
                "/world/executed_path",
                segs.astype(np.float32),
                PATH_COLOUR,
                thickness=self._line * 1.5,
            )


def robot_frame(scenario: Scenario, model: mujoco.MjModel):
    """The frame the planner's trajectories are positions of (the robot's ``frame``)."""
    return FrameResolver(model, scenario.robot.spec.frame)("robot")


# ------------------------------------------------------------------------------ live


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
    messages per wall second (the replay draws trajectories, it does not need every one)."""

    def __init__(self, path: Path, hz: float = 20.0):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = self.path.open("w", buffering=1)
        self._period = 1.0 / hz
        self._last = -np.inf

    def write(self, msg: P.Diagnostics) -> None:
        now = time.monotonic()
        if now - self._last < self._period:
            return
        self._last = now
        self._f.write(json.dumps(diagnostics_record(msg)) + "\n")

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
        self.robot = robot_frame(scenario, self.model)
        self.controls = controls  # False: the page only shows (pause, reset, move: none)
        self.server = viser_server(host, port, f"m3p2i {scenario.name}")
        self.drawing = SceneDrawing(self.server, self.model, self.data)
        self.info = PanelInfo(scenario=scenario.name)
        self.ctx = zmq.Context()
        self.state_sub = socket(self.ctx, zmq.SUB, conflate=True)
        self.state_sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.diag_sub = socket(self.ctx, zmq.SUB, conflate=True)
        self.diag_sub.setsockopt(zmq.SUBSCRIBE, b"")
        if keys is not None:
            # CURVE, as a tool beside the planner: the planner's pair; the world's key checked
            # on the state socket, the planner's own on its diagnostics socket
            curve_client(self.state_sub, keys.own, keys.world)
            curve_client(self.diag_sub, keys.own, keys.own.public)
        self.state_sub.connect(endpoints.state)
        self.diag_sub.connect(endpoints.diagnostics)
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
            g.on_drag_start(lambda _, g=g: setattr(g, "dragging", True))
            g.on_drag_end(lambda _, name=obj.name, g=g: self._moved(name, g))
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

    def _moved(self, name: str, gizmo) -> None:
        gizmo.dragging = False
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
        end = None if duration is None else time.monotonic() + duration
        last_scene = last_panel = 0.0
        state = diag = None
        while not self.stop.is_set() and (end is None or time.monotonic() < end):
            events = dict(poller.poll(20))
            if self.state_sub in events:
                state = self._receive(self.state_sub, "state") or state
            if self.diag_sub in events:
                got = self._receive(self.diag_sub, "diagnostics")
                if got is not None:
                    diag = got
                    self._diagnostics(got)
            now = time.monotonic()
            if state is not None and now - last_scene >= 1 / _SCENE_HZ:
                self._state(state)
                if diag is not None:
                    self.drawing.set_top(diag.top, diag.top_modes)
                    self.drawing.set_guide(diag.guide)
                    diag = None
                state = None
                last_scene = now
            if now - last_panel >= 1 / _PANEL_HZ:
                self.panel.content = self.info.markdown()
                last_panel = now

    def _receive(self, sock, kind: str):
        try:
            return P.decode(sock.recv(), expect=kind)
        except P.ProtocolError as exc:
            log.warning("ignored a %s message: %s", kind, exc)
            return None

    def _state(self, state: P.State) -> None:
        try:
            set_state(self.model, self.data, vars(state))
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
        if not self._path or np.linalg.norm(p - self._path[-1]) > _PATH_STEP:
            self._path.append(p)
            self.drawing.set_path(np.array(self._path))
        self.drawing.set_poses(self.data)
        for body, g in self.gizmos.values():
            if not g.dragging:
                g.position = self.data.xpos[body].copy()
                g.wxyz = self.data.xquat[body].copy()
        self.info.status, self.info.time, self.info.extras = state.status, state.time, state.extras

    def _diagnostics(self, d: P.Diagnostics) -> None:
        now = time.monotonic()
        self._diag_times.append(now)
        if len(self._diag_times) > 1:
            span = self._diag_times[-1] - self._diag_times[0]
            self.info.planner_hz = (len(self._diag_times) - 1) / span if span > 0 else None
        self.info.plan_ms = d.plan_time * 1000
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
            for s in (self.state_sub, self.diag_sub):
                s.close(0)
            self.ctx.term()
            if self.record is not None:
                self.record.close()
        if not keep_server:
            self.server.stop()


# ------------------------------------------------------------------------------ replay


@dataclass
class Replay:
    """An episode log ready to draw: its step records, action changes, metrics and, when
    recorded, the planner's diagnostics by state seq."""

    scenario: Scenario
    steps: list[dict]
    actions: list[tuple[float, str]]
    summary: dict | None
    diagnostics: dict[int, dict]
    disturbances: list[dict]

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
    path = episode.find_log(log_path)
    records = episode.read_log(path)
    sc = episode.log_scenario(records, scenario)
    steps = episode.steps(records)
    if not steps:
        raise ValueError(f"{path}: no step records to replay (the episode never started)")
    summary = episode.summary(records)
    actions = [
        (float(r["time"]), r["action"])
        for r in records
        if r.get("kind") == "event" and r.get("what") == "action"
    ]
    disturbances = [
        r for r in records if r.get("kind") == "event" and r.get("what") == "disturbance"
    ]
    diag_path = path.parent / "diagnostics.jsonl"
    diags = {int(r["seq"]): r for r in episode.read_log(diag_path)} if diag_path.is_file() else {}
    return Replay(sc, steps, actions, summary, diags, disturbances)


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
        self.path = self._robot_path()
        times = replay.times
        self.stop = threading.Event()
        gui = self.server.gui
        self.panel = gui.add_markdown("")
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
        info = PanelInfo(
            scenario=self.replay.scenario.name,
            time=float(step["time"]),
            status=f"replay, step {i + 1} of {len(self.replay.steps)}",
            action=step.get("action", ""),
            extras=step.get("extras") or {},
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
    from shared.evaluation.replay import load_step

    load_step(model, data, step)
