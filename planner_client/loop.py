"""The planner client's loop (paper Alg. 1): state in -> task layer -> M3P2I -> command out.

Connection handling: the handshake is retried until a server answers (a refusal, e.g. another
scenario, is fatal with the server's reason); the first state after a handshake whose arrays have
other sizes than the planner's model is fatal too (:class:`LayoutMismatch`: a bridge of another
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
from collections.abc import Callable
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import zmq

from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.evaluation.metrics import mean_hz
from shared.hardware import steps_of
from shared.layout import StateSizes
from shared.scene import STATE_FIELDS, get_full_state
from shared.scenario import DelayConfig
from shared.security import Authenticator, HandshakeMonitor, PlannerKeys, curve_client, \
    curve_server, describe_handshake_failure
from shared.timed_plan import TimedPlan, held
from planner_client.attach import Attachments
from planner_client.delay_estimate import ActuationDelayEstimate
from planner_client.motion import Iteration, MotionPlanner
from planner_client.mirror import Mirror, MocapState
from planner_client.task import TaskLayer
from planner_client.timing import LeadEstimate, predict, steps_between

log = logging.getLogger("m3p2i.planner")

_NEW_EPISODE = 1.0   # world time going back more than this (s) is a reset, not jitter
_HANDSHAKE_FAILURES = 20  # failed handshakes in a row, no reply between: a key problem (a
                          # wrong key fails ~10 times a second; a restarting world not so)


class HandshakeRefused(RuntimeError):
    """The server refused us (scenario or protocol mismatch); retrying cannot help."""


class LayoutMismatch(RuntimeError):
    """The world's first state after a handshake has other array sizes than the planner's model
    of the scenario: a bridge of another layout (retrying cannot help). ``mismatches`` names
    each array that differs."""

    def __init__(self, scenario: str, mismatches: list[str]):
        self.scenario, self.mismatches = scenario, mismatches
        super().__init__(self.explain(scenario))

    def explain(self, scenario_ref: str) -> str:
        """The message, with ``m3p2i layout scenario_ref`` as where to find the right layout."""
        return (f"the world's state does not fit the planner's model of {self.scenario}: "
                f"{'; '.join(self.mismatches)}. `m3p2i layout {scenario_ref}` prints the "
                f"layout a world must send, index by index")


@dataclass
class LoopStats:
    iterations: int = 0
    plan_times: list[float] = field(default_factory=list)
    action_changes: list[tuple[float, str, tuple[str, ...]]] = field(default_factory=list)
    final_status: str = ""
    safe_fallbacks: int = 0     # commands that were the safe control because there was no plan

    @property
    def hz(self) -> float:
        return mean_hz(self.plan_times)


Renew = Callable[[int | None], tuple[MotionPlanner, TaskLayer]]
"""Builds the planner and task layer afresh for a new episode, sampling with the given seed
(None: the planner's own)."""


class PlannerClient:
    def __init__(self, planner: MotionPlanner, task: TaskLayer, endpoints: Endpoints,
                 scenario_name: str, scenario_hash: str, server_timeout: float = 2.0,
                 exit_on_done: bool = True, diagnostics: bool = True,
                 keys: PlannerKeys | None = None, diagnostics_host: str | None = None,
                 renew: Renew | None = None, delays: DelayConfig | None = None,
                 max_rate: float = 0.0):
        """``renew``: when given, each new session of the world after the first (a new episode:
        a world reset with a seed, or restarted) gets a planner and task layer as a fresh
        process would build them, so no warm start, belief or random stream carries over.
        ``delays``: the robot's unseen delays to compensate (default: the scenario's
        ``planner.delays``). ``max_rate``: at most this many iterations per wall-clock second
        (0: as fast as it can), to rehearse on a fast machine what a slower computer does."""
        self.planner = planner
        self.task = task
        self.renew = renew
        self.endpoints = endpoints
        self.hello = P.Hello(scenario=scenario_name, scenario_hash=scenario_hash,
                             versions=list(P.VERSIONS))
        self.version = P.PROTOCOL_VERSION   # of the commands: the one the world chose
        self._warned_version: int | None = None
        self.server_timeout = server_timeout
        self.exit_on_done = exit_on_done
        self.delays = delays or planner.problem.scenario.planner.delays
        self.min_period = 1.0 / max_rate if max_rate > 0 else 0.0
        self._bind(planner)
        self.keys = keys
        self.ctx = zmq.Context()
        self.sub = socket(self.ctx, zmq.SUB, conflate=True)   # only the newest state matters
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self._secure(self.sub)
        self.sub.connect(endpoints.state)
        self.push = socket(self.ctx, zmq.PUSH, conflate=True)  # never queue stale commands
        self._secure(self.push)
        self.push.connect(endpoints.command)
        self.diag = None
        self.auth = None
        self._listeners = 0     # distinct subscriptions to the diagnostics (see _listened)
        if diagnostics:
            # XPUB, not PUB: it tells when someone subscribes, so that the diagnostics (the
            # viewer's top trajectories: a tenth of navigation's planning work) are made only
            # for a listener
            self.diag = socket(self.ctx, zmq.XPUB)
            if keys is not None:   # the planner is the CURVE server of its diagnostics
                self.auth = Authenticator(self.ctx, keys.viewers, "the planner's diagnostics")
                curve_server(self.diag, keys.own)
            # bound on this machine (loopback unless told): the world's address, the default,
            # is another machine's when the two run apart
            self.diag.bind(Endpoints(diagnostics_host or endpoints.host,
                                     endpoints.port).diagnostics)
        self.welcome: P.Welcome | None = None
        self.stats = LoopStats()
        self._action: tuple[str, tuple[str, ...]] | None = None
        self.robot = planner.problem.robot
        self._last_ctrl = self.robot.safe_stop()
        self._answered: tuple[str, int] | None = None   # (session, seq) of the last command
        self._answer = b""
        # what the world plays, oldest first: enough plans to cover a lead plus declared delays
        self._sent: deque[TimedPlan] = deque(maxlen=16)
        self._lead: LeadEstimate | None = None
        self._actuation: ActuationDelayEstimate | None = None   # planner.delays.estimate
        self._acting_logged: int | None = None     # the delays last logged, in world steps
        self._ahead_logged = 0
        self._last_start: tuple[float, int] | None = None   # (t_eff, state seq) of the last plan
        self._faults = 0        # consecutive iterations without a plan (Iteration.fault)
        self._handshake_failures = 0   # in a row, since the last reply
        self._layout_checked = False   # whether a state since the last handshake was checked

    # ------------------------------------------------------------------ handshake

    def handshake(self, retry: float = 1.0, give_up: float | None = None) -> P.Welcome:
        """Send hello until a server answers; raise HandshakeRefused on an error reply.

        The hello offers :data:`P.VERSIONS`, written in the oldest; the world answers in the one
        it chose. A world from before the negotiation refuses that hello with an error of its
        own version and no ``versions``: then the plain hello of that version is sent, once."""
        start = time.monotonic()
        warned = False
        plain: int | None = None    # the version of a world that does not negotiate
        while True:
            req = socket(self.ctx, zmq.REQ)
            self._secure(req)
            monitor = HandshakeMonitor(req, hangups=True)
            req.connect(self.endpoints.control)
            req.send(P.encode(self.hello, min(P.VERSIONS)) if plain is None else
                     P.encode(dataclasses.replace(self.hello, versions=None), plain))
            try:
                answered = self._await_reply(req, monitor, retry)
            except HandshakeRefused:
                req.close(0)   # an open socket would block the context's termination
                raise
            finally:
                monitor.close()
            if answered:
                frame = req.recv()
                req.close(0)
                try:
                    reply, version = P.decode_versioned(frame, expect=("welcome", "error"),
                                                        versions=P.VERSIONS)
                except P.ProtocolError as exc:
                    raise HandshakeRefused(f"server sent an invalid reply: {exc}") from None
                if isinstance(reply, P.Error):
                    plain = self._plain_hello(reply, version, plain)
                    continue
                self._speak(version)
                if reply.nu != self.planner.problem.model.nu:
                    raise HandshakeRefused(f"server model has nu={reply.nu}, planner model has "
                                           f"nu={self.planner.problem.model.nu}")
                log.info("connected: %s, %s mode, dt %.3f s, session %s", reply.scenario,
                         reply.mode, reply.dt, reply.session)
                if self.welcome is not None and reply.session != self.welcome.session:
                    self._new_episode(reply.seed)
                self.welcome = reply
                self._layout_checked = False
                # a lock-step world reports its state delay in state.lag too (0 without one)
                self._lead = LeadEstimate(reply.dt) \
                    if reply.mode == "realtime" or self.delays.estimate else None
                self._actuation = None
                if self.delays.estimate:
                    self._actuation = ActuationDelayEstimate(
                        self.planner.problem.model, reply.dt, steps_of(self.delays.max_ms, reply.dt))
                    # the plans the world played that long ago must still be at hand
                    self._sent = deque(maxlen=max(16, self._actuation.max_steps + 8))
                self._sent.clear()
                self._last_start = None
                return reply
            req.close(0)   # a REQ that got no reply cannot send again: make a fresh one
            if not warned:
                log.info("waiting for a server at %s ...", self.endpoints.control)
                warned = True
            if give_up is not None and time.monotonic() - start > give_up:
                raise TimeoutError(f"no server answered at {self.endpoints.control} "
                                   f"within {give_up:.0f} s")

    def _plain_hello(self, error: P.Error, version: int, plain: int | None) -> int:
        """The version to say a plain hello in after the world refused ours with ``error``
        (written in ``version``); raises :class:`HandshakeRefused` when retrying cannot help."""
        if plain is None and error.versions is None and version in P.VERSIONS:
            log.info("the world (protocol version %d) does not negotiate versions (%s): "
                     "saying hello in version %d", version, error.reason, version)
            return version
        if version not in P.VERSIONS and error.versions is None:
            raise HandshakeRefused(f"{error.reason} (the world speaks protocol version {version}, "
                                   f"this planner speaks versions {P.VERSIONS_TEXT})")
        raise HandshakeRefused(error.reason)

    def _speak(self, version: int) -> None:
        """Commands from now on in ``version``, the world's choice; an older one is said once."""
        self.version = version
        if version < P.PROTOCOL_VERSION and self._warned_version != version:
            self._warned_version = version
            log.warning("the world speaks protocol version %d only: commands carry no plan, and "
                        "it holds each command's ctrl until the next (the robot follows the "
                        "planner's lag)", version)

    def _new_episode(self, seed: int | None) -> None:
        """Start over for a new episode of the world (``renew``), sampling with the world's
        episode seed when it sends one."""
        if self.renew is None:
            return
        log.info("new episode%s: planner and task layer rebuilt",
                 f" (seed {seed})" if seed is not None else "")
        self.planner.close()
        self.planner, self.task = self.renew(seed)
        self._bind(self.planner)
        self._action = None
        self._last_ctrl = self.robot.safe_stop()
        self._faults = 0

    def _bind(self, planner: MotionPlanner) -> None:
        """The mirror of the world in ``planner``'s model, and its attachments."""
        pc = planner.problem.scenario.planner
        self.mirror = Mirror(planner.problem.model, estimate=pc.estimate,
                             planar=[n for n, o in pc.model.objects.items() if o.planar])
        self.attachments = Attachments(planner.problem.model, pc.model.attach,
                                       held_filter=pc.estimate.held_filter)

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
                self._handshake_failures += 1
                why = describe_handshake_failure(event, value)
                if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
                    raise HandshakeRefused(
                        f"the world at {self.endpoints.control} refused this planner's key "
                        f"({why}): " + (f"its public key {self.keys.own.public.decode()} "
                                        f"must be in the world's DIR/world/planners/ (copy "
                                        f"DIR/planner/planner.key there and restart the "
                                        f"world)" if self.keys else "start it with --keys DIR"))
                mismatch = event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == 0x11000002
                if mismatch or self._handshake_failures >= _HANDSHAKE_FAILURES:
                    raise HandshakeRefused(
                        f"no secure handshake with the world at {self.endpoints.control} "
                        f"({why}): " + (
                            "either DIR/planner/world.key is not this world's public key, or "
                            "the world runs without keys" if self.keys else
                            "the world requires CURVE keys: start the planner with --keys DIR "
                            "(the planner/ part of `m3p2i keys DIR`)"))
        return False

    # ------------------------------------------------------------------ loop

    def run(self, max_iterations: int | None = None,
            on_plan: Callable[[P.State, Iteration], None] | None = None) -> LoopStats:
        """Plan until the episode ends (or forever with ``exit_on_done=False``)."""
        self.handshake()
        last_state_at = time.monotonic()
        while max_iterations is None or self.stats.iterations < max_iterations:
            if not self.sub.poll(200):
                if time.monotonic() - last_state_at > self.server_timeout:
                    log.warning("server silent for %.1f s; reconnecting", self.server_timeout)
                    self.handshake()
                    last_state_at = time.monotonic()
                continue
            try:
                state = P.decode(self.sub.recv(), expect="state", versions=P.VERSIONS)
            except P.ProtocolError as exc:
                log.warning("dropped a bad state message: %s", exc)
                continue
            last_state_at = time.monotonic()
            if state.session != self.welcome.session:
                log.info("new session %s (the world restarted or began a new episode); handshaking again",
                         state.session)
                self.handshake()
                continue
            if not self._layout_checked:
                self._check_layout(state)
            if state.status != "running":
                self.stats.final_status = state.status
                log.info("episode over: %s at t=%.2f s", state.status, state.time)
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
            self._step(state, on_plan)
            if self.min_period:
                # idle, not busy: a throttled planner must leave the cores to the world
                time.sleep(max(0.0, began + self.min_period - time.monotonic()))
        return self.stats

    def _check_layout(self, state: P.State) -> None:
        """Raise :class:`LayoutMismatch` when the first state of a session does not fit the
        planner's model (a bridge sending another layout: every state would be dropped)."""
        mismatches = StateSizes.of(self.planner.problem.model).mismatches(
            {name: getattr(state, name) for name in STATE_FIELDS})
        if mismatches:
            raise LayoutMismatch(self.hello.scenario, mismatches)
        self._layout_checked = True

    def _step(self, state: P.State, on_plan) -> None:
        t0 = time.perf_counter()
        try:
            x0 = self.mirror.apply(state)
        except ValueError as exc:
            log.error("state does not fit the planner's model: %s", exc)
            return
        if self.attachments.track(self.mirror.data, self.mirror.received_qpos):
            x0 = self.mirror.refresh()
        if self._actuation is not None:
            self._actuation.observe(self.mirror.data, list(self._sent),
                                    self.robot.safe_stop(self._last_ctrl))
        decision = self.task.decide(self.mirror.data, state.extras, state.time)
        if self.attachments.welds:
            self.attachments.update(self.mirror.data, self.task.last_observation, state.time)
        self.planner.set_modes(decision.modes)
        start, x0, mocap = self._plan_start(state, x0)
        it = self.planner.iterate(x0, mocap)
        self._note_fault(it, state.time)
        if decision.stop or it.fault is not None:
            # a safe stop keeps the hold_ctrl actuators where they were: a gripper keeps its grip;
            # without a plan (no finite cost) nothing else is safe to send
            ctrl, plan = self.robot.safe_stop(self._last_ctrl), None
            self._sent.append(held(ctrl, start, state.seq))
        else:
            ctrl, plan = it.command, it.plan
            self._sent.append(TimedPlan(start, self.planner.dt, plan, state.seq))
        self._last_ctrl = ctrl
        plan_time = time.perf_counter() - t0
        self._answer = P.encode(P.Command(
            session=state.session, seq=state.seq, ctrl=ctrl, plan_time=plan_time,
            action=decision.action, plan_ctrl=plan, plan_t0=None if plan is None else start,
            plan_dt=None if plan is None else self.planner.dt), self.version)
        self._answered = (state.session, state.seq)
        self.push.send(self._answer)
        steps = state.seq - self._last_start[1] if self._last_start else 0
        self._last_start = (start, state.seq)
        self.stats.iterations += 1
        self.stats.plan_times.append(plan_time)
        key = (decision.action, tuple(decision.modes))
        if key != self._action:
            self._action = key
            self.stats.action_changes.append((state.time, decision.action, tuple(decision.modes)))
            log.info("t=%.2f s: action %s, modes %s", state.time, decision.action, list(decision.modes))
        if self.diag is not None and self._listened():
            r = it.result
            self.diag.send(P.encode(P.Diagnostics(
                seq=state.seq, action=decision.action, alternatives=list(decision.alternatives),
                mode_names=it.modes, mode_weights=r.mode_weights.numpy(),
                top=it.top, plan_time=plan_time, lead=start - state.time, steps=steps,
                top_modes=it.top_modes)))
        if on_plan is not None:
            on_plan(state, it)

    def _plan_start(self, state: P.State, x0: np.ndarray) -> tuple[float, np.ndarray, MocapState | None]:
        """When the new plan takes effect, the state predicted for then, and the mocap bodies
        there; the warm start is moved by the time since the last plan's start.

        Real time: ``lead`` whole world steps after the state (the largest recent lag), the
        mirror stepped over them under the plans the world is playing. Lock-step: the state's
        own time, as received, plus the declared state delay (``planner.delays``) or, with
        ``estimate``, the one the world reports in ``state.lag``. The actuation delay, declared
        or estimated, is predicted beyond the plan's date (planner_client.timing).
        """
        mocap = self.mirror.mocap()
        ahead = acting = 0      # world steps from the state to the plan's date, and on to when it acts
        lockstep = self.welcome is None or self.welcome.mode != "realtime"
        if self._lead is not None:
            self._lead.observe(state.lag)
            ahead = self._lead.steps()
        if lockstep and ahead and ahead != self._ahead_logged:
            log.info("t=%.2f s: state delay measured at %d world steps (%.0f ms)", state.time,
                     ahead, ahead * self.welcome.dt * 1000)
            self._ahead_logged = ahead
        if lockstep and self.delays.state_ms:
            # in real time the lag runs from the state's measurement time, so the lead already
            # holds the state delay; in lock-step it is the declared one, or the lag measured
            ahead = max(ahead, steps_of(self.delays.state_ms, self.welcome.dt))
        if self.delays.actuation_ms:
            acting = steps_of(self.delays.actuation_ms, self.welcome.dt)
        estimated = self._actuation.steps() if self._actuation is not None else None
        if estimated is not None:
            acting = estimated
            if estimated != self._acting_logged:
                log.info("t=%.2f s: actuation delay estimated at %d world steps (%.0f ms)",
                         state.time, estimated, estimated * self.welcome.dt * 1000)
                self._acting_logged = estimated
        start = state.time
        if ahead + acting:
            dt = self.welcome.dt
            model, data = self.mirror.model, self.mirror.data
            predict(model, data, list(self._sent), self.robot.safe_stop(self._last_ctrl), dt,
                    ahead + acting, acting * dt)
            x0 = get_full_state(model, data, self.mirror.x0)
            start = float(data.time) - acting * dt    # the same instant, in the mirror's float sums
            if mocap is not None and mocap.moving:
                mocap = MocapState(mocap.pos + mocap.vel * (float(data.time) - state.time),
                                   mocap.quat, mocap.vel)
        if self._last_start is not None and start >= self._last_start[0] - _NEW_EPISODE:
            self.planner.advance(steps_between(self._last_start[0], start, self.planner.dt))
        return start, x0, mocap

    def _note_fault(self, it: Iteration, time: float) -> None:
        """Logs a run of iterations without a plan once, when it starts and when it ends."""
        if it.fault is None:
            if self._faults:
                log.info("t=%.2f s: planning resumed after %d iteration(s) on the safe control",
                         time, self._faults)
            self._faults = 0
            return
        if not self._faults:
            log.warning("t=%.2f s: %s; sending the safe control until a plan is finite again",
                        time, it.fault)
        self._faults += 1
        self.stats.safe_fallbacks += 1

    def _listened(self) -> bool:
        """Whether anyone subscribes to the diagnostics now. XPUB hands up each distinct
        subscription when it is first made (a message starting with byte 1) and when its last
        subscriber leaves or disconnects (byte 0); only that first byte is read, and at most
        64 messages an iteration (the rest wait for the next)."""
        for _ in range(64):
            try:
                msg = self.diag.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            if msg[:1] == b"\x01":
                self._listeners += 1
            elif msg[:1] == b"\x00":
                self._listeners = max(0, self._listeners - 1)
        return self._listeners > 0

    def close(self) -> None:
        self.planner.close()
        for s in (self.sub, self.push, self.diag):
            if s is not None:
                s.close(0)
        if self.auth is not None:
            self.auth.stop()
        self.ctx.term()
