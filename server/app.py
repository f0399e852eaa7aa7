"""The world server's network loop: handshake, state publishing, command intake, episode log.

Lock-step: state ``seq`` is published and the world waits for the command answering it (the
state is re-published every ``republish`` seconds meanwhile, for late subscribers). Real-time:
the world holds its start state until the first command, then steps on the wall clock playing
the newest command's time-indexed plan (:mod:`shared.timed_plan`; a command without a plan holds
its ``ctrl``); when the plan runs out, or no command arrived for ``command_timeout``, the robot's
safe control (zero velocity) holds until a fresh one arrives. Bad messages are logged with their reason and dropped; nothing received is executed.

The world is anything implementing :class:`server.interface.World` (the simulated
:class:`server.world.SimWorld` by default, a user's bridge with ``--world``): this loop only
calls its methods, never MuJoCo's data. With hardware faults (``--hardware``, the scenario's
``hardware:`` section; docs/hardware.md) it is wrapped in :class:`server.hardware.FaultyWorld`.
"""

from __future__ import annotations

import logging
import secrets
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zmq

from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.evaluation.episode import episode_log_path
from shared.evaluation.metrics import MetricsEvaluator, describe, mean_hz
from shared.evaluation.timing import describe_timing, timing_summary
from shared.hardware import HardwareConfig
from shared.scenario import Scenario
from shared.security import Authenticator, HandshakeMonitor, WorldKeys, curve_server, \
    describe_handshake_failure
from shared.timed_plan import PlanPlayer, TimedPlan, held
from server.episode_log import EpisodeLog, read_log
from server.hardware import FaultyWorld
from server.interface import Outcome, World, world_name
from server.world import SimWorld

log = logging.getLogger("m3p2i.server")

_KEEP_STATE_TIMES = 4096   # states whose times are kept, for the age of the commands answering them


@dataclass
class ServerOptions:
    mode: str = "lockstep"            # lockstep | realtime
    command_timeout: float = 0.5      # realtime: seconds before a command is stale
    republish: float = 0.2            # lockstep: re-send the pending state this often
    linger: float = 0.5               # seconds to keep publishing the final state
    realtime_factor: float = 1.0      # realtime: simulated seconds per wall second
    wait_planner: float = 0.0         # seconds to wait for the first command; 0 = forever
    plan_every: int = 1               # lockstep: world steps played per command (a slow planner)
    keep_serving: bool = False        # after an episode, wait for a seeded reset (warm bench workers)


class WorldServer:
    def __init__(self, scenario: Scenario, endpoints: Endpoints, log_path: Path,
                 options: ServerOptions | None = None, viewer=None, seed: int = 0,
                 keys: WorldKeys | None = None, world: type[World] = SimWorld,
                 hardware: HardwareConfig | None = None):
        self.scenario = scenario
        # the faults the world shows (docs/hardware.md): --hardware's, else the scenario's
        self.hardware = scenario.hardware if hardware is None else hardware
        self.world_class = world          # built afresh for each episode: world(scenario, seed)
        self.world: World | None = None
        self.opt = options or ServerOptions()
        self.log_template = str(log_path)
        self.viewer = viewer
        self.ctx = zmq.Context()
        self.rep = socket(self.ctx, zmq.REP)
        self.pub = socket(self.ctx, zmq.PUB)
        self.pull = socket(self.ctx, zmq.PULL)
        # CURVE: the world is the server of all three sockets; ZAP (a thread) accepts only the
        # allow-listed planner keys, so a refused peer gets no state, no welcome, no say
        self.auth = Authenticator(self.ctx, keys.allowed, "the world") if keys else None
        self.curve = keys is not None
        self._sockets = {"control": self.rep, "state": self.pub, "command": self.pull}
        for s in self._sockets.values():
            if keys is not None:
                curve_server(s, keys.own)
        # failed handshakes (a peer without keys, or with another world key) never reach ZAP:
        # only the socket monitor tells, and the world must say why nobody is answering
        self.monitors = {name: HandshakeMonitor(s) for name, s in self._sockets.items()}
        for s, addr in ((self.rep, endpoints.control), (self.pub, endpoints.state),
                        (self.pull, endpoints.command)):
            s.bind(addr)
        self.poller = zmq.Poller()
        self.poller.register(self.rep, zmq.POLLIN)
        self.poller.register(self.pull, zmq.POLLIN)
        for m in self.monitors.values():
            self.poller.register(m.mon, zmq.POLLIN)
        self._refused = 0
        self._rejected = 0
        self.version = P.PROTOCOL_VERSION    # states are written in it: the newest handshake's
        self._stop = False
        self._next_seed: int | None = None   # a seeded reset asked for this episode next
        self._begin_episode(seed)

    def _begin_episode(self, seed: int) -> None:
        """A new episode from ``seed``'s start: a fresh world (as a new process would build it),
        a new session (the planner re-handshakes and starts over) and its own episode log."""
        if self.world is not None:
            self.world.close()
        self.world = self.world_class(self.scenario, seed)
        if self.hardware.active:
            self.world = FaultyWorld(self.world, self.hardware,
                                     realtime=self.opt.mode == "realtime",
                                     realtime_factor=self.opt.realtime_factor)
        self.world.reset()
        self.metrics = MetricsEvaluator(self.scenario, self.world.model)   # bad frames fail here
        self.session = secrets.token_hex(4)
        self.seed = seed
        self.seq = 0
        self._over = False                # the summary is written; a kept world waits for a reset
        self._ending = False              # the safe stop, metrics and summary are being written
        self._in_step = False             # a world step is between its physics and its log record
        self._pending: int | None = None  # a signal that landed there, raised once it is logged
        self._plan_times: list[float] = []
        self._state_times: dict[int, float] = {}     # seq -> world time of recent states
        self._plan_time_of: dict[int, float] = {}    # seq -> planning time, until first applied
        self._lag = 0.0                               # of the newest command, world seconds
        self.player = PlanPlayer()
        self._action = ""
        self.action_changes: list[tuple[float, str]] = []
        self._paused = False              # control op pause: the world neither steps nor waits out time
        self._published = -1              # the newest seq published (or lost: drop_state)
        self.dropped = 0                  # states the simulated link lost
        self.log = EpisodeLog(episode_log_path(self.log_template, seed))
        self.log.write("header", scenario=self.scenario.name, scenario_hash=self.scenario.hash,
                       source=self.scenario.source, mode=self.opt.mode, dt=self.world.dt,
                       session=self.session, nq=self.world.model.nq, nu=self.world.model.nu,
                       seed=seed, initial=self.world.initial, curve=self.curve,
                       world=world_name(self.world_class),
                       **(self.world.header() if isinstance(self.world, FaultyWorld) else {}))

    # ------------------------------------------------------------------ loop

    def run(self) -> Outcome:
        """Serve one episode (with ``keep_serving``, one after another until ``shutdown``);
        each log is always closed with its summary, even on Ctrl-C. Returns the last outcome."""
        log.info("serving %s (%s mode) on %s%s", self.scenario.name, self.opt.mode,
                 self.rep.getsockopt_string(zmq.LAST_ENDPOINT),
                 ", CURVE: only allow-listed planner keys" if self.auth else "")
        try:
            while True:
                outcome = self._serve_episode()
                if not self.opt.keep_serving or not self._await_next_episode():
                    return outcome
                self._begin_episode(self._next_seed)
                self._next_seed = None
        finally:
            self.close()

    def _serve_episode(self) -> Outcome:
        try:
            if self.opt.mode == "lockstep":
                self._run_lockstep()
            else:
                self._run_realtime()
            if not self.opt.keep_serving:   # a kept world publishes its final state until the next
                self._linger()
        except KeyboardInterrupt:
            self._stop = True
            self.world.status = "stopped"
            log.info("interrupted")
        finally:
            self._ending = True                  # a signal from now on must not cost the summary
            self._stop_world()                   # a robot holds still whatever ended the episode
            if self.world.status == "running":   # ended by a seeded reset
                self.world.status = "stopped"
            outcome = self.world.outcome()
            hz = mean_hz(self._plan_times)
            metrics, timing = self._episode_metrics(outcome.status)
            self.log.write("summary", status=outcome.status, time=outcome.time,
                           measures=outcome.measures, planner_hz=hz, steps=self.seq,
                           rejected=self._rejected, actions=self.action_changes,
                           **({"dropped": self.dropped} if self.hardware.active else {}),
                           metrics=metrics, timing=timing)
            self.log.close()
            self._over = True
        outcome.measures["planner_hz"] = hz
        return outcome

    def interrupt(self, signum: int, frame=None) -> None:
        """SIGINT/SIGTERM handler (the CLI installs it): end the episode as Ctrl-C does, and
        serve no other. While the episode is ending (safe stop, metrics, summary) it raises
        nothing: a supervisor's SIGTERM that lands just as an episode ends would otherwise cut
        the log before its summary. Within a world step it raises once the step is logged: a
        step taken but not logged would leave the world ahead of its log, and the summary's step
        count one past the last step record (a CI run of 2026-12-01 caught that)."""
        self._stop = True
        if self._ending:
            return
        if self._in_step:
            self._pending = signum
            return
        raise KeyboardInterrupt(f"signal {signum}")

    def _stop_world(self) -> None:
        """The world's safe stop; its failure is logged loudly, and the summary still written."""
        try:
            self.world.stop()
        except Exception as exc:   # noqa: BLE001 - the operator must hear of it, and the log end
            log.exception("the world's safe stop failed: the robot may still be moving")
            self.log.event("stop_failed", reason=f"{type(exc).__name__}: {exc}")

    def _await_next_episode(self) -> bool:
        """Between episodes of a kept world: publish the final state (so planners know the
        episode is over) and serve control until a reset (True) or a shutdown (False)."""
        log.info("episode over (%s): waiting for a reset with the next seed", self.world.status)
        while not self._stop and self._next_seed is None:
            self._publish()
            try:
                self._poll(self.opt.republish)
            except KeyboardInterrupt:
                return False
        return self._next_seed is not None and not self._stop

    def _episode_metrics(self, status: str) -> tuple[dict | None, dict | None]:
        """shared.evaluation's metrics and timing of the logged steps (the log is line-buffered,
        so complete on disk). A failure here is logged, never allowed to cost the summary."""
        try:
            records = read_log(self.log.path)
            metrics = self.metrics.evaluate(records, status=status)
            timing = timing_summary(records)
        except Exception:   # noqa: BLE001 - the summary must be written whatever went wrong
            log.exception("could not compute the episode metrics")
            return None, None
        log.info("metrics: %s", describe(metrics))
        log.info("timing: %s", describe_timing(timing))
        return metrics.as_dict(), timing

    def _running(self) -> bool:
        return self.world.status == "running" and not self._stop and self._next_seed is None

    def _run_lockstep(self) -> None:
        self._publish()
        while (cmd := self._next_command(lambda c: c.seq == self.seq)) is not None:
            self._count_plan(cmd)
            self._play_lockstep(cmd)
            self._note_action(cmd.action)

    def _next_command(self, wanted) -> P.Command | None:
        """The next valid command ``wanted`` accepts, the pending state re-published every
        ``republish`` seconds meanwhile (for late subscribers); None when stopped. Before the
        first step, ``wait_planner`` seconds without one raise."""
        started = last_pub = time.monotonic()
        while self._running():
            cmd = self._poll(self.opt.republish)
            # paused: the command is dropped; the planner sends it again for the re-published state
            if cmd is not None and wanted(cmd) and not self._paused:
                return cmd
            if time.monotonic() - last_pub >= self.opt.republish:
                if self.seq == 0 and self.opt.wait_planner and not self._paused and \
                        time.monotonic() - started > self.opt.wait_planner:
                    raise TimeoutError(f"no planner command within {self.opt.wait_planner} s")
                self._publish()
                last_pub = time.monotonic()
        return None

    def _play_lockstep(self, cmd: P.Command) -> None:
        """``plan_every`` world steps under the command (its plan's knots by time, or its ctrl
        held; the safe control past the plan's end), then the state is published. One step by
        default; more emulate, deterministically, a planner that slow against a real-time world."""
        plan = (TimedPlan(cmd.plan_t0, cmd.plan_dt, cmd.plan_ctrl, cmd.seq) if cmd.has_plan
                else held(cmd.ctrl, self.world.time, cmd.seq))
        # the lag, as in real time: from the answered state's time (its measurement's) to now;
        # 0 unless the world publishes its states late (a state delay)
        self._lag = max(0.0, self.world.time - self._state_times.get(cmd.seq, self.world.time))
        for _ in range(self.opt.plan_every):
            self._apply(plan.at(self.world.time), cmd.seq, publish=False)
            if not self._running():
                break
        self._publish()

    def _run_realtime(self) -> None:
        period = self.world.dt / self.opt.realtime_factor
        latest_at = -np.inf
        stale = True
        ended = -1                       # seq of the last plan whose end was logged
        # the clock starts with the planner: its start-up (imports, model compilation) is not
        # part of the episode
        self._publish()
        cmd = self._next_command(lambda c: True)
        next_tick = time.monotonic()
        while self._running():
            if cmd is not None:
                latest_at = time.monotonic()
                self._receive(cmd)
            now = time.monotonic()
            if self._paused:
                # the world's clock stands still (plans are dated in world time, so they stay
                # valid); the state is re-published so the planner does not take the world for lost
                if now >= next_tick:
                    self._publish()
                    next_tick = now + self.opt.republish
                cmd = self._poll(max(0.0, min(next_tick - now, self.opt.republish)))
                if not self._paused:
                    next_tick = time.monotonic()
                continue
            if now >= next_tick:
                fresh = now - latest_at <= self.opt.command_timeout
                if fresh and stale:
                    self.log.event("commands_fresh", seq=self.seq)
                elif not fresh and not stale:
                    log.warning("no command for %.2f s: holding the robot (safe control)",
                                self.opt.command_timeout)
                    self.log.event("commands_stale", seq=self.seq, age=now - latest_at)
                    self.player.clear()
                stale = not fresh
                ctrl, source = self._playing() if fresh else (None, -1)
                cmd_age = now - latest_at if latest_at > -np.inf else None
                if ctrl is None and source >= 0 and source != ended:
                    ended = source
                    log.warning("the plan of state %d ran out at t=%.2f s: safe control until "
                                "the next", source, self.world.time)
                    self.log.event("plan_ended", seq=source, time=self.world.time)
                self._apply(ctrl, source, cmd_age=cmd_age)
                next_tick += period
                if now - next_tick > 10 * period:   # fell far behind (debugger, load): resync
                    next_tick = now
            cmd = self._poll(max(0.0, next_tick - time.monotonic()))

    def _receive(self, cmd: P.Command) -> None:
        """A real-time command: its lag (published as ``state.lag``) and its plan, if any; a
        command without a plan holds its ``ctrl`` until the next one (protocol 1's meaning)."""
        sent = self._state_times.get(cmd.seq)
        if sent is not None:
            self._lag = max(0.0, self.world.time - sent)
        self._count_plan(cmd)
        self._note_action(cmd.action)
        self.player.receive(TimedPlan(cmd.plan_t0, cmd.plan_dt, cmd.plan_ctrl, cmd.seq)
                            if cmd.has_plan else held(cmd.ctrl, self.world.time, cmd.seq))

    def _count_plan(self, cmd: P.Command) -> None:
        """Its planning time counts (Hz statistics) once, on the first step it drives."""
        if cmd.plan_time > 0:
            self._plan_time_of[cmd.seq] = cmd.plan_time

    def _playing(self) -> tuple[np.ndarray | None, int]:
        """The control for the world's time and the state ``seq`` it was planned from;
        ``(None, seq)`` when that plan ran out, ``(None, -1)`` before any command."""
        ctrl, plan = self.player.control(self.world.time)
        return ctrl, (plan.seq if plan is not None else -1)

    def _linger(self) -> None:
        end = time.monotonic() + self.opt.linger
        while time.monotonic() < end and not self._stop:
            self._publish()
            self._poll(0.05)

    # ------------------------------------------------------------------ steps

    def _note_action(self, action: str) -> None:
        if action != self._action:
            self._action = action
            self.action_changes.append((self.world.time, action))
            self.log.event("action", time=self.world.time, action=action)

    def _apply(self, ctrl: np.ndarray | None, source: int = -1, publish: bool = True,
               cmd_age: float | None = None) -> None:
        """One world step under ``ctrl`` (None: the safe control), planned from state
        ``source`` (-1: none); the step's log record has the control's age (world seconds since
        that state) and source, from which shared.evaluation.timing tells whether the planner
        kept up. Real time also records ``cmd_age``: wall seconds from the newest command's
        arrival to the moment this step's control was chosen (what the stale-command watchdog
        compares with ``command_timeout``; None before the first command and in lock-step), so
        a soak test can prove from the log that no stale command drove the robot."""
        now = self.world.time
        source = source if ctrl is not None else -1
        age = now - self._state_times.get(source, now) if source >= 0 else 0.0
        plan_time = self._plan_time_of.pop(source, 0.0)
        if plan_time:
            self._plan_times.append(plan_time)
        self._in_step = True              # from the physics to its log record: no signal between
        try:
            self.world.step(self.world.safe_command() if ctrl is None else ctrl)
            for event in self.world.events:
                log.info("disturbance: %s moved at t=%.2f s", event["object"], event["time"])
                self.log.event("disturbance", **event)
            self.world.events.clear()
            self.seq += 1
            s = self.world.true_state()
            self.log.write("step", seq=self.seq, time=s.time, qpos=s.qpos, qvel=s.qvel,
                           act=s.act, mocap_pos=s.mocap_pos, mocap_quat=s.mocap_quat,
                           ctrl=self.world.ctrl, action=self._action, safe=ctrl is None,
                           plan_seq=source, age=age, plan_time=plan_time, cmd_age=cmd_age,
                           extras=self.world.extras)
        finally:
            self._in_step = False
        if self._pending is not None:
            signum, self._pending = self._pending, None
            raise KeyboardInterrupt(f"signal {signum}")
        if self.viewer is not None:
            self.viewer.sync()
        if publish:
            self._publish()

    def _publish(self) -> None:
        """The world's current state as state ``seq``. A state the world's
        link loses (:meth:`World.drop_state`, asked once per ``seq``) is not sent: lock-step
        re-sends it on the ``republish`` timer (the loss costs wall time, never world time),
        real time sends the next step's."""
        s = self.world.state()
        state = P.State(session=self.session, seq=self.seq, time=s.time, qpos=s.qpos,
                        qvel=s.qvel, act=s.act, mocap_pos=s.mocap_pos, mocap_quat=s.mocap_quat,
                        status=self.world.status, extras=dict(self.world.extras), lag=self._lag)
        self._state_times[self.seq] = state.time
        self._state_times.pop(self.seq - _KEEP_STATE_TIMES, None)
        self._plan_time_of.pop(self.seq - _KEEP_STATE_TIMES, None)
        if self.seq != self._published:
            self._published = self.seq
            if self.world.drop_state():
                self.dropped += 1
                return
        self.pub.send(P.encode(state, self.version))

    def _poll(self, timeout_s: float) -> P.Command | None:
        """Serve control requests and drain commands; return the newest valid command."""
        newest = None
        events = dict(self.poller.poll(int(timeout_s * 1000)))
        self._note_refusals()
        if self.rep in events:
            self._serve_control()
        if self.pull in events:
            while True:
                try:
                    frame = self.pull.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                cmd = self._accept_command(frame)
                if cmd is not None:
                    newest = cmd
        return newest

    def _accept_command(self, frame: bytes) -> P.Command | None:
        try:
            cmd = P.decode(frame, expect="command", versions=P.VERSIONS)
        except P.ProtocolError as exc:
            return self._reject(str(exc))
        if cmd.session != self.session:
            return None   # for an earlier run of this server: silently outdated, not malformed
        if cmd.ctrl.shape != (self.world.model.nu,):
            return self._reject(f"command.ctrl has shape {list(cmd.ctrl.shape)}, "
                                f"the model needs [{self.world.model.nu}]")
        return cmd

    def _note_refusals(self) -> None:
        """Peers that security refused, into the episode log: a key outside the allow list
        (the ZAP thread already logged it with the peer's address), a peer without keys or one
        holding another world public key (logged here, from the socket monitors)."""
        found = [(f"key {r.key} from {r.address} is not in the allow list", True)
                 for r in (self.auth.refusals() if self.auth else [])]
        for name, m in self.monitors.items():
            for event, value in m.failures():
                if event != zmq.EVENT_HANDSHAKE_FAILED_AUTH:   # AUTH: the ZAP refusal above
                    found.append((f"handshake on the {name} socket failed: "
                                  f"{describe_handshake_failure(event, value)}", False))
        for reason, logged in found:
            self._refused += 1
            sampled = self._refused <= 10 or self._refused % 100 == 0   # a peer retrying
            if sampled and not logged:
                log.warning("refused a peer (%d so far): %s", self._refused, reason)
            if self._refused <= 100 or self._refused % 100 == 0:
                self.log.event("peer_refused", reason=reason, count=self._refused)

    def _reject(self, reason: str) -> None:
        self._rejected += 1
        if self._rejected <= 10 or self._rejected % 100 == 0:
            log.warning("rejected message (%d so far): %s", self._rejected, reason)
        self.log.event("rejected", reason=reason)
        return None

    def _serve_control(self) -> None:
        frame = self.rep.recv()
        try:
            msg, version = P.decode_versioned(frame, expect=("hello", "control"),
                                              versions=P.VERSIONS)
        except P.ProtocolError as exc:
            self._reject(str(exc))
            self.rep.send(P.encode(P.Error(reason=f"refused: {exc}")))
            return
        if isinstance(msg, P.Control):
            self._control(msg)
            return
        # a planner that offered versions learns from an error's own ones that we negotiated
        speaks = list(P.VERSIONS) if msg.versions is not None else None
        try:
            chosen = P.choose_version(msg, version)
        except P.ProtocolError as exc:
            reason = f"refused: {exc}"
            log.error(reason)
            self.log.event("handshake_refused", reason=reason)
            self.rep.send(P.encode(P.Error(reason=reason, versions=speaks)))
            return
        if msg.scenario_hash != self.scenario.hash:
            reason = (f"scenario mismatch: the server runs {self.scenario.name!r} "
                      f"(hash {self.scenario.hash}), the planner loaded {msg.scenario!r} "
                      f"(hash {msg.scenario_hash}); start both with the same scenario file")
            log.error(reason)
            self.log.event("handshake_refused", reason=reason)
            self.rep.send(P.encode(P.Error(reason=reason, versions=speaks), chosen))
            return
        self.log.event("handshake", client=msg.client, version=chosen)
        log.info("planner connected (%s, protocol version %d)", msg.client, chosen)
        self.version = chosen
        self.rep.send(P.encode(P.Welcome(
            scenario=self.scenario.name, scenario_hash=self.scenario.hash, mode=self.opt.mode,
            dt=self.world.dt, nu=int(self.world.model.nu), session=self.session,
            seed=self.seed if self.opt.keep_serving else None), chosen))
        self._publish()

    def _control(self, msg: P.Control) -> None:
        """A control op: echoed when done, answered with ``error`` and its reason when refused
        (an unknown or robot body to move); either way logged."""
        if msg.op == "move":
            try:
                event = self.world.move_object(msg.object, msg.pos, msg.quat)
            except ValueError as exc:
                log.warning("control move refused: %s", exc)
                self.log.event("control_refused", op=msg.op, object=msg.object, reason=str(exc))
                self.rep.send(P.encode(P.Error(reason=f"move refused: {exc}")))
                return
            log.info("disturbance: %s moved by a control op at t=%.2f s", msg.object, event["time"])
            self.log.event("control", op=msg.op, object=msg.object)
            self.log.event("disturbance", **event)
            # a new state: a lock-step world waits for the command answering the moved one
            self.seq += 1
            self._publish()
        elif msg.op == "reset" and msg.seed is not None and not self.opt.keep_serving:
            reason = ("a reset with a seed begins a new episode, and this world serves one: "
                      "start it with --keep-serving")
            self.log.event("control_refused", op=msg.op, reason=reason)
            self.rep.send(P.encode(P.Error(reason=f"reset refused: {reason}")))
            return
        else:
            self.log.event("control", op=msg.op, **({"seed": msg.seed} if msg.seed is not None else {}))
        if msg.op == "shutdown":
            self._stop = True
            self.world.status = "stopped"
        elif msg.op == "reset" and self.opt.keep_serving and (msg.seed is not None or self._over):
            # run() ends this episode and begins the seed's (after one: the same seed again)
            self._next_seed = self.seed if msg.seed is None else msg.seed
        elif msg.op == "reset":
            self.world.reset()
            self.seq += 1
            self._publish()
        elif msg.op in ("pause", "resume"):
            if self._paused != (msg.op == "pause"):
                log.info("world %s at t=%.2f s", "paused" if msg.op == "pause" else "resumed",
                         self.world.time)
            self._paused = msg.op == "pause"
            if self._paused:
                self._stop_world()       # a robot must not go on with its last command
        self.rep.send(P.encode(msg))

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        for m in self.monitors.values():
            m.close()
        for s in (self.rep, self.pub, self.pull):
            s.close(0)
        if self.auth is not None:
            self.auth.stop()
        self.ctx.term()
