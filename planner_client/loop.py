"""The planner client: the paper's control loop (:class:`planner_client.controller.Controller`,
thesis Alg. 1) served over ZeroMQ to a world server.

The client owns the sockets, the handshake, reconnections, CURVE security, the re-sent answer
to a re-published lock-step state, the ``max_rate`` throttle and the diagnostics publishing; each
new state goes to the controller, and its command to the world.

Connection handling: the handshake is retried until a server answers (a refusal, e.g. another
scenario, is fatal with the server's reason); the first state after a handshake whose arrays have
other sizes than the planner's model is fatal too (``LayoutMismatch``: a bridge of another
layout). A server that goes silent for ``server_timeout`` seconds, or comes back with a new
session, is handshaken again, so the planner outlives server restarts. Each received state is
answered with one command that echoes its ``seq``.

Each command carries the whole plan, dated: its first knot is for the world time at which the
command is expected to take effect (:mod:`planner_client.timing`). Against a real-time world the
planner plans from its prediction of the state at that time and moves its warm start by the world
time that really passed; in lock-step that time is one step and the lead is zero.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import zmq

from planner_client.controller import Controller, LoopStats
from planner_client.keys import PlannerKeys, curve_client
from planner_client.perception.field_message import FIELD_TOPIC, FieldPublisher
from planner_client.phases import STARTUP
from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.security import (
    Authenticator,
    HandshakeMonitor,
    curve_server,
    describe_handshake_failure,
)

log = logging.getLogger("m3p2i.planner")

STATE_QUEUE = 256  # states a planner holds unread: 2.5 s of a 100 Hz world
_HANDSHAKE_FAILURES = 20  # failed handshakes in a row, no reply between: a key problem (a
# wrong key fails ~10 times a second; a restarting world not so)


class HandshakeRefused(RuntimeError):
    """The server refused us (scenario or protocol mismatch); retrying cannot help."""


class PlannerClient:
    """A :class:`Controller` served over ZeroMQ: states from a world server in, its commands
    (and, for listeners, its diagnostics) out."""

    def __init__(
        self,
        controller: Controller,
        endpoints: Endpoints,
        scenario_name: str,
        scenario_hash: str,
        server_timeout: float = 2.0,
        exit_on_done: bool = True,
        diagnostics: bool = True,
        keys: PlannerKeys | None = None,
        diagnostics_host: str | None = None,
        max_rate: float = 0.0,
        robot: str | None = None,
        robot_index: int = 0,
    ):
        """``controller``: the loop each state is handed to; with its ``renew``, each new
        session of the world after the first (a new episode: a world reset with a seed, or
        restarted) gets a planner and task layer as a fresh process would build them.
        ``max_rate``: at most this many iterations per wall-clock second (0: as fast as it
        can), to rehearse on a fast machine what a slower computer does. ``robot``: in a
        team's world, the robot this planner drives, ``robot_index`` its place in the team
        (its diagnostics port is ``port + 3 + robot_index``)."""
        self.controller = controller
        self.endpoints = endpoints
        self.hello = P.Hello(
            scenario=scenario_name,
            scenario_hash=scenario_hash,
            versions=list(P.VERSIONS) if robot is None else [P.PROTOCOL_VERSION],
            robot=robot,
        )
        self.version = P.PROTOCOL_VERSION  # of the commands: the one the world chose
        self._warned_version: int | None = None
        self.server_timeout = server_timeout
        self.exit_on_done = exit_on_done
        self.min_period = 1.0 / max_rate if max_rate > 0 else 0.0
        self.keys = keys
        self.ctx = zmq.Context()
        # not conflated: a real-time world's states carry each sensor reading once, so the
        # loop drains every state waiting, plans on the newest and keeps the readings of the
        # others (_newest); the queue is bounded, and a world that overruns it drops states
        self.sub = socket(self.ctx, zmq.SUB)
        self.sub.setsockopt(zmq.RCVHWM, STATE_QUEUE)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self._secure(self.sub)
        self.sub.connect(endpoints.state)
        self.push = socket(self.ctx, zmq.PUSH, conflate=True)  # never queue stale commands
        self._secure(self.push)
        self.push.connect(endpoints.command)
        self.diag = None
        self.auth = None
        self._listeners = 0  # distinct subscriptions to the diagnostics (see _listened)
        self._field_listeners = 0  # of them, to the map's field (a browser view's)
        self._fields = FieldPublisher()
        if diagnostics:
            # XPUB, not PUB: it tells when someone subscribes, so that the diagnostics (the
            # viewer's top trajectories: a tenth of navigation's planning work) are made only
            # for a listener
            self.diag = socket(self.ctx, zmq.XPUB)
            if keys is not None:  # the planner is the CURVE server of its diagnostics
                self.auth = Authenticator(self.ctx, keys.viewers, "the planner's diagnostics")
                curve_server(self.diag, keys.own)
            # bound on this machine (loopback unless told): the world's address, the default,
            # is another machine's when the two run apart
            # a team's robots' planners: one port each, in the team's order from the fourth
            host = diagnostics_host or endpoints.host
            self.diag.bind(Endpoints(host, endpoints.port + robot_index).diagnostics)
        self.welcome: P.Welcome | None = None
        self._answered: tuple[str, int] | None = None  # (session, seq) of the last command
        self._answer = b""
        self._handshake_failures = 0  # in a row, since the last reply
        self._layout_checked = False  # whether a state since the last handshake was checked
        self.dropped_states = 0  # states refused by the decoder (docs/protocol.md, "Bad input")

    # ------------------------------------------------------------------ handshake

    def handshake(self, retry: float = 1.0, give_up: float | None = None) -> P.Welcome:
        """Send hello until a server answers; raise HandshakeRefused on an error reply.

        The hello offers :data:`P.VERSIONS`, written in the oldest; the world answers in the one
        it chose. A world from before the negotiation refuses that hello with an error of its
        own version and no ``versions``: then the plain hello of that version is sent, once."""
        start = time.monotonic()
        warned = False
        plain: int | None = None  # the version of a world that does not negotiate
        while True:
            req = socket(self.ctx, zmq.REQ)
            self._secure(req)
            monitor = HandshakeMonitor(req, hangups=True)
            req.connect(self.endpoints.control)
            req.send(
                P.encode(self.hello, min(self.hello.versions))
                if plain is None
                else P.encode(dataclasses.replace(self.hello, versions=None), plain)
            )
            try:
                answered = self._await_reply(req, monitor, retry)
                if not answered and monitor.stalled:
                    # connected, and the handshake neither succeeded nor failed in ``retry``
                    # seconds: a CURVE world hanging up on a keyless planner without a word
                    # (rare, under load) looks like this; a world that is up completes a
                    # handshake in milliseconds
                    self._count_handshake_failure("connected, but no handshake completed")
                elif not answered and self._handshake_failures and not monitor.events:
                    # after failed handshakes, no connection at all: the world that refused us
                    # is gone (its episode ended and it exited: seen under load, 15 failures,
                    # then no listener on its port), so this counts as well. Before any failed
                    # handshake the same silence is a world not started yet, which the planner
                    # waits for (either may start first): a keyless planner that only comes up
                    # after a CURVE world exited cannot tell and waits
                    self._count_handshake_failure("no connection since the handshakes failed")
            except HandshakeRefused:
                req.close(0)  # an open socket would block the context's termination
                raise
            finally:
                monitor.close()
            if answered:
                frame = req.recv()
                req.close(0)
                try:
                    reply, version = P.decode_versioned(
                        frame, expect=("welcome", "error"), versions=P.VERSIONS
                    )
                except P.ProtocolError as exc:
                    raise HandshakeRefused(f"server sent an invalid reply: {exc}") from None
                if isinstance(reply, P.Error):
                    plain = self._plain_hello(reply, version, plain)
                    continue
                self._speak(version)
                self._welcomed(reply)
                return reply
            req.close(0)  # a REQ that got no reply cannot send again: make a fresh one
            if not warned:
                log.info("waiting for a server at %s ...", self.endpoints.control)
                warned = True
            if give_up is not None and time.monotonic() - start > give_up:
                raise TimeoutError(
                    f"no server answered at {self.endpoints.control} within {give_up:.0f} s"
                )

    def _welcomed(self, reply: P.Welcome) -> None:
        """Begin planning for the world of ``reply`` (a new episode when its session is new);
        HandshakeRefused when its controls are not this planner's."""
        problem = self.controller.motion.problem  # a team robot's: its own controls
        nu = problem.model.nu if self.hello.robot is None else len(problem.actuators)
        if reply.nu != nu:
            raise HandshakeRefused(f"server model has nu={reply.nu}, planner model has nu={nu}")
        log.info(
            "connected: %s, %s mode, dt %.3f s, session %s",
            reply.scenario,
            reply.mode,
            reply.dt,
            reply.session,
        )
        new = self.welcome is not None and reply.session != self.welcome.session
        if self.min_period and reply.mode != "realtime" and self.welcome is None:
            log.warning(
                "--max-rate %g: a lock-step world waits for every plan, so it only slows the "
                "episode (m3p2i-server --plan-every rehearses a slow planner)",
                1.0 / self.min_period,
            )
        self.controller.begin(reply.mode, reply.dt, reply.seed, new_episode=new)
        self.welcome = reply
        self._layout_checked = False

    def _plain_hello(self, error: P.Error, version: int, plain: int | None) -> int:
        """The version to say a plain hello in after the world refused ours with ``error``
        (written in ``version``); raises :class:`HandshakeRefused` when retrying cannot help."""
        if plain is None and error.versions is None and version in P.VERSIONS:
            log.info(
                "the world (protocol version %d) does not negotiate versions (%s): "
                "saying hello in version %d",
                version,
                error.reason,
                version,
            )
            return version
        if version not in P.VERSIONS and error.versions is None:
            raise HandshakeRefused(
                f"{error.reason} (the world speaks protocol version {version}, "
                f"this planner speaks versions {P.VERSIONS_TEXT})"
            )
        raise HandshakeRefused(error.reason)

    def _speak(self, version: int) -> None:
        """Commands from now on in ``version``, the world's choice; version 1 (commands without
        a plan) is said once. A version-2 world only sends no scans."""
        self.version = version
        if version == 1 and self._warned_version != version:
            self._warned_version = version
            log.warning(
                "the world speaks protocol version %d only: commands carry no plan, and "
                "it holds each command's ctrl until the next (the robot follows the "
                "planner's lag)",
                version,
            )

    def _secure(self, sock: zmq.Socket) -> None:
        """A socket to the world: a CURVE client holding the world's public key, with keys."""
        if self.keys is not None:
            curve_client(sock, self.keys.own, self.keys.world)

    def _await_reply(self, req: zmq.Socket, monitor: HandshakeMonitor, retry: float) -> bool:
        """Whether the world answered within ``retry`` seconds. A world that refused our key,
        or that speaks another security mechanism, never answers: that raises with the fix
        instead of waiting for ever. libzmq does not always say which (a peer that hangs up
        mid-handshake is reported without detail), so a few failed handshakes in a row raise
        too; a world still starting up refuses connections, it does not fail handshakes."""
        poller = zmq.Poller()
        poller.register(req, zmq.POLLIN)
        poller.register(monitor.mon, zmq.POLLIN)
        end = time.monotonic() + retry
        while (left := end - time.monotonic()) > 0:
            events = dict(poller.poll(int(left * 1000) + 1))
            if req in events:
                self._handshake_failures = 0
                return True
            for event, value in monitor.failures():
                why = describe_handshake_failure(event, value)
                if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
                    raise HandshakeRefused(
                        f"the world at {self.endpoints.control} refused this planner's key "
                        f"({why}): "
                        + (
                            f"its public key {self.keys.own.public.decode()} "
                            f"must be in the world's DIR/world/planners/ (copy "
                            f"DIR/planner/planner.key there and restart the "
                            f"world)"
                            if self.keys
                            else "start it with --keys DIR"
                        )
                    )
                mismatch = event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == 0x11000002
                self._count_handshake_failure(why, at_once=mismatch)
        return False

    def _count_handshake_failure(self, why: str, at_once: bool = False) -> None:
        """One more failed handshake in a row; raise the fix once it cannot be a world that
        is still starting (``at_once``: a mechanism mismatch, which only keys explain)."""
        self._handshake_failures += 1
        if at_once or self._handshake_failures >= _HANDSHAKE_FAILURES:
            raise HandshakeRefused(
                f"no secure handshake with the world at {self.endpoints.control} ({why}): "
                + (
                    "either DIR/planner/world.key is not this world's public key, or "
                    "the world runs without keys"
                    if self.keys
                    else "the world requires CURVE keys: start the planner with --keys DIR "
                    "(the planner/ part of `m3p2i keys DIR`)"
                )
            )

    # ------------------------------------------------------------------ loop

    def run(self, max_iterations: int | None = None) -> LoopStats:
        """Plan until the episode ends (or forever with ``exit_on_done=False``)."""
        self.handshake()
        if STARTUP.steps:
            STARTUP.mark("handshake")
        last_state_at = time.monotonic()
        while max_iterations is None or self.stats.iterations < max_iterations:
            if not self.sub.poll(200):
                if time.monotonic() - last_state_at > self.server_timeout:
                    log.warning("server silent for %.1f s; reconnecting", self.server_timeout)
                    self.handshake()
                    last_state_at = time.monotonic()
                continue
            state = self._newest()
            if state is None:
                continue
            last_state_at = time.monotonic()
            if state.session != self.welcome.session:
                log.info(
                    "new session %s (the world restarted or began a new episode); "
                    "handshaking again",
                    state.session,
                )
                self.handshake()
                continue
            if not self._layout_checked:
                self.controller.check_layout(state)
                self._layout_checked = True
            if self.controller.over(state):
                if self.exit_on_done:
                    break
                continue
            if (state.session, state.seq) == self._answered:
                # a lock-step world re-publishes a state until its command arrives: planning
                # it again would shift the warm start and draw new noise, so a busy machine
                # would change the episode; the same command again is harmless
                self.push.send(self._answer)
                continue
            began = time.monotonic()
            self._step(state)
            if self.min_period:
                # idle, not busy: a throttled planner must leave the cores to the world
                time.sleep(max(0.0, began + self.min_period - time.monotonic()))
        return self.stats

    def _newest(self) -> P.State | None:
        """The newest state waiting (None: only bad messages), carrying the sensor readings of
        the states it overtook that were never answered, oldest first: a planner slower than
        the world plans on the newest state, and its map still gets every reading."""
        states = []
        while True:
            try:
                raw = self.sub.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            try:
                states.append(P.decode(raw, expect="state", versions=P.VERSIONS))
            except P.ProtocolError as exc:
                self.dropped_states += 1  # said for the first ten, then every hundredth
                if self.dropped_states <= 10 or self.dropped_states % 100 == 0:
                    log.warning(
                        "dropped a bad state message (%d so far): %s", self.dropped_states, exc
                    )
        if not states:
            return None
        newest = states[-1]
        answered = self._answered[1] if self._answered else -1
        # a re-published state (same seq) carries the same readings: each seq's once
        seqs, carried = {newest.seq}, []
        for s in states[:-1]:
            if s.session == newest.session and s.seq > answered and s.seq not in seqs:
                seqs.add(s.seq)
                carried += s.scans
        if not carried:
            return newest
        return dataclasses.replace(newest, scans=carried + list(newest.scans))

    @property
    def stats(self) -> LoopStats:
        return self.controller.stats

    def _step(self, state: P.State) -> None:
        """Answer ``state`` with the controller's command, then publish its diagnostics when
        someone listens (and the map's newest field when a view does)."""
        command = self.controller.step(state)
        if command is None:
            return
        self._answer = P.encode(command, self.version)
        self._answered = (state.session, state.seq)
        self.push.send(self._answer)
        if STARTUP.steps and "first command" not in STARTUP.totals:
            STARTUP.mark("first command")
            log.info("start-up: %s", STARTUP.report())
        if self.diag is not None and self._listened():
            self.diag.send(P.encode(self.controller.diagnostics()))
            if self._field_listeners and self.controller.map is not None:
                frame = self._fields.frame(self.controller.map.latest())
                if frame is not None:
                    self.diag.send(frame)

    def _listened(self) -> bool:
        """Whether anyone subscribes to the diagnostics now. XPUB hands up each distinct
        subscription when it is first made (a message starting with byte 1) and when its last
        subscriber leaves or disconnects (byte 0), then the subscription's topic: only
        :data:`FIELD_TOPIC`'s is told apart (the map's field is made for it alone); at most 64
        messages an iteration (the rest wait for the next)."""
        for _ in range(64):
            try:
                msg = self.diag.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            field = msg[1:] == FIELD_TOPIC
            if msg[:1] == b"\x01":
                self._listeners += 1
                self._field_listeners += field
            elif msg[:1] == b"\x00":
                self._listeners = max(0, self._listeners - 1)
                self._field_listeners = max(0, self._field_listeners - field)
        return self._listeners > 0

    def close(self) -> None:
        self.controller.close()
        for s in (self.sub, self.push, self.diag):
            if s is not None:
                s.close(0)
        if self.auth is not None:
            self.auth.stop()
        self.ctx.term()
