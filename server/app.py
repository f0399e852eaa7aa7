"""The world server's network loop: handshake, state publishing, command intake, control ops.

The episode itself (the world, its log, the steps commands drive, the summary) is
:class:`server.episode.Episode`; this module serves it over ZeroMQ and schedules its steps.
Lock-step: state ``seq`` is published and the world waits for the command answering it (the
state is re-published every ``republish`` seconds meanwhile, for late subscribers). Real-time:
the world holds its start state until the first command, then steps on the wall clock playing
the newest command's time-indexed plan (:mod:`shared.timed_plan`; a command without a plan holds
its ``ctrl``); when the plan runs out, or no command arrived for ``command_timeout``, the robot's
safe control (zero velocity) holds until a fresh one arrives. Bad messages are logged with their
reason and dropped; nothing received is executed.

The world is anything implementing :class:`server.interface.World` (the simulated
:class:`server.world.SimWorld` by default, a user's bridge with ``--world``): this loop only
calls its methods, never MuJoCo's data. With simulated faults (``--faults``, the scenario's
``faults:`` section; docs/faults.md) it is wrapped in :class:`server.faults.FaultyWorld`.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zmq

from server.episode import Episode
from server.episode_log import EpisodeLog
from server.evaluation.log_reader import episode_log_path
from server.interface import Outcome, World
from server.keys import WorldKeys
from server.world import SimWorld
from shared import protocol as P
from shared.endpoints import Endpoints, socket
from shared.scenario import Scenario
from shared.scenario.faults import FaultConfig
from shared.security import (
    Authenticator,
    HandshakeMonitor,
    curve_server,
    describe_handshake_failure,
)

log = logging.getLogger("m3p2i.server")


@dataclass
class ServerOptions:
    mode: str = "lockstep"  # lockstep | realtime
    command_timeout: float = 0.5  # realtime: seconds before a command is stale
    republish: float = 0.2  # lockstep: re-send the pending state this often
    linger: float = 0.5  # seconds to keep publishing the final state
    realtime_factor: float = 1.0  # realtime: simulated seconds per wall second
    wait_planner: float = 0.0  # seconds to wait for the first command; 0 = forever
    plan_every: int = 1  # lockstep: world steps played per command (a slow planner)
    keep_serving: bool = False  # after an episode, wait for a seeded reset (warm bench workers)


class AddressUnavailable(OSError):
    """The world's ports cannot be bound (taken by another process, or not this machine's)."""


def choose_version(hello: P.Hello, version: int, speaks: tuple[int, ...] = P.VERSIONS) -> int:
    """The version a world answers ``hello`` (written in ``version``) in: the highest both
    speak. A hello without ``versions`` (a planner from before the negotiation) speaks its own
    ``v`` only. Raises :class:`shared.protocol.ProtocolError` naming both sides' versions when
    none is common."""
    offered = hello.versions if hello.versions is not None else [version]
    common = set(offered) & set(speaks)
    if not common:
        raise P.ProtocolError(
            f"no common protocol version: the planner speaks {P.version_names(offered)}, "
            f"this world speaks {P.version_names(speaks)}"
        )
    return max(common)


class WorldServer:
    def __init__(
        self,
        scenario: Scenario,
        endpoints: Endpoints,
        log_path: Path,
        options: ServerOptions | None = None,
        viewer=None,
        seed: int = 0,
        keys: WorldKeys | None = None,
        world: type[World] = SimWorld,
        faults: FaultConfig | None = None,
    ):
        self.scenario = scenario
        # the faults the world shows (docs/faults.md): --faults's, else the scenario's
        self.faults = scenario.faults if faults is None else faults
        self.world_class = world  # built afresh for each episode: world(scenario, seed)
        self.episode: Episode | None = None
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
        try:
            for s, addr in (
                (self.rep, endpoints.control),
                (self.pub, endpoints.state),
                (self.pull, endpoints.command),
            ):
                s.bind(addr)
        except zmq.ZMQError as exc:  # e.g. another world on these ports: nothing half-open
            self.close()
            why = os.strerror(exc.errno) if exc.errno else str(exc)
            raise AddressUnavailable(f"cannot serve on {addr}: {why}") from None
        self.poller = zmq.Poller()
        self.poller.register(self.rep, zmq.POLLIN)
        self.poller.register(self.pull, zmq.POLLIN)
        for m in self.monitors.values():
            self.poller.register(m.mon, zmq.POLLIN)
        self._refused = 0
        self._rejected = 0
        self._inbox: list[P.Command] = []  # commands received, not yet taken (await_command)
        self.version = P.PROTOCOL_VERSION  # states are written in it: the newest handshake's
        self._stop = False
        self._next_seed: int | None = None  # a seeded reset asked for this episode next
        self._begin_episode(seed)

    def _begin_episode(self, seed: int) -> None:
        """A new episode from ``seed``'s start: a fresh world (as a new process would build it),
        a new session (the planner re-handshakes and starts over) and its own episode log."""
        path = self._log_path(seed)
        if self.episode is not None:
            self.episode.world.close()
        self.episode = Episode(
            self.scenario,
            seed,
            path,
            self.world_class,
            self.faults,
            self.opt.mode,
            self.curve,
            realtime_factor=self.opt.realtime_factor,
        )
        self._ending = False  # the safe stop, metrics and summary are being written
        self._paused = False  # control op pause: the world neither steps nor waits out time

    def _log_path(self, seed: int) -> Path:
        """The log of ``seed``'s episode. A later episode of a kept world never overwrites a
        log on disk (a seed served again): it gets ``-2``, ``-3``, ... before the suffix."""
        path = episode_log_path(self.log_template, seed)
        if self.episode is None:
            return path
        free, n = path, 2
        while free.exists():
            free, n = path.with_name(f"{path.stem}-{n}{path.suffix}"), n + 1
        if free != path:
            log.info("seed %d served before: its episode log is %s", seed, free)
        return free

    @property
    def world(self) -> World:
        """The current episode's world."""
        return self.episode.world

    @property
    def log(self) -> EpisodeLog:
        """The current episode's log."""
        return self.episode.log

    # ------------------------------------------------------------------ loop

    def run(self) -> Outcome:
        """Serve one episode (with ``keep_serving``, one after another until ``shutdown``);
        each log is always closed with its summary, even on Ctrl-C. Returns the last outcome."""
        log.info(
            "serving %s (%s mode) on %s%s",
            self.scenario.name,
            self.opt.mode,
            self.rep.getsockopt_string(zmq.LAST_ENDPOINT),
            ", CURVE: only allow-listed planner keys" if self.auth else "",
        )
        try:
            while True:
                outcome = self.serve_episode()
                if not self.opt.keep_serving or not self._await_next_episode():
                    return outcome
                self.next_episode()
        finally:
            self.close()

    def serve_episode(self) -> Outcome:
        """Serve the episode begun last until it ends (success, time-out, a stop), then write
        its safe stop, metrics and summary, whatever happened; returns its outcome."""
        try:
            if self.opt.mode == "lockstep":
                self._run_lockstep()
            else:
                self._run_realtime()
            if not self.opt.keep_serving:  # a kept world publishes its final state until the next
                self._linger()
        except KeyboardInterrupt:
            self._stop = True
            self.episode.abort()
            log.info("interrupted")
        finally:
            self._ending = True  # a signal from now on must not cost the summary
            outcome = self.episode.finish(self._rejected)
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
        if self.episode.in_step:
            self.episode.pending = signum
            return
        raise KeyboardInterrupt(f"signal {signum}")

    def _await_next_episode(self) -> bool:
        """Between episodes of a kept world: publish the final state (so planners know the
        episode is over) and serve control until a reset (True) or a shutdown (False)."""
        log.info("episode over (%s): waiting for a reset with the next seed", self.world.status)
        while not self._stop and self._next_seed is None:
            self.publish()
            try:
                self.serve(self.opt.republish)
            except KeyboardInterrupt:
                return False
        return self._next_seed is not None and not self._stop

    @property
    def running(self) -> bool:
        """Whether the episode goes on: the world running, no stop asked, no reset pending."""
        return self.world.status == "running" and not self._stop and self._next_seed is None

    @property
    def paused(self) -> bool:
        """Control op ``pause``: the world neither steps nor waits out time."""
        return self._paused

    def stop(self) -> None:
        """End the episode after the current step and serve no other (as a signal does,
        without raising)."""
        self._stop = True

    def next_episode(self) -> None:
        """Begin the episode a ``reset`` with a seed asked for (a kept world, between
        episodes)."""
        self._begin_episode(self._next_seed)
        self._next_seed = None

    def _run_lockstep(self) -> None:
        """Each state waits for the command answering it; ``plan_every`` world steps under it,
        then the next state (:meth:`Episode.play`)."""
        self.publish()
        while (cmds := self._await_team(lambda c: c.seq == self.episode.seq)) is not None:
            play = cmds if self.scenario.team else cmds[0]
            self.episode.play(play, self.opt.plan_every, self._after_step)
            self.publish()

    def _await_team(self, wanted) -> list[P.Command] | None:
        """A command ``wanted`` accepts from every robot's planner (a team's world waits for
        all of them, in the team's order); None when stopped."""
        names = [m.name for m in self.scenario.team] or [None]
        got: dict[str | None, P.Command] = {}
        while len(got) < len(names):
            cmd = self.await_command(lambda c: wanted(c) and c.robot not in got)
            if cmd is None:
                return None
            got[cmd.robot] = cmd
        return [got[n] for n in names]

    def await_command(self, wanted) -> P.Command | None:
        """The next valid command ``wanted`` accepts, the pending state re-published every
        ``republish`` seconds meanwhile (for late subscribers); None when stopped. Before the
        first step, ``wait_planner`` seconds without one raise. Commands that arrived together
        wait their turn (a team's planners answer the same state)."""
        started = last_pub = time.monotonic()
        while self.running:
            self._inbox = [c for c in self._inbox + self.serve(self.opt.republish) if wanted(c)]
            # paused: the command is dropped; the planner sends it again for the re-published state
            if self._paused:
                self._inbox.clear()
            elif self._inbox:
                return self._inbox.pop(0)
            if time.monotonic() - last_pub >= self.opt.republish:
                if (
                    self.episode.seq == 0
                    and self.opt.wait_planner
                    and not self._paused
                    and time.monotonic() - started > self.opt.wait_planner
                ):
                    raise TimeoutError(f"no planner command within {self.opt.wait_planner} s")
                self.publish()
                last_pub = time.monotonic()
        return None

    def _run_realtime(self) -> None:
        period = self.world.dt / self.opt.realtime_factor
        robots = [m.name for m in self.scenario.team] or [None]
        latest_at = dict.fromkeys(robots, -np.inf)  # each robot's newest command, monotonic s
        stale = dict.fromkeys(robots, True)
        ended = -1  # seq of the last plan whose end was logged
        # the clock starts with the planners: their start-up (imports, model compilation) is
        # not part of the episode
        self.publish()
        cmds = self._await_team(lambda c: True) or []
        next_tick = time.monotonic()
        while self.running:
            for cmd in cmds:
                if not self._outdated(cmd):
                    latest_at[cmd.robot] = time.monotonic()
                    self.episode.receive(cmd)
            now = time.monotonic()
            if self._paused:
                # the world's clock stands still (plans are dated in world time, so they stay
                # valid); the state is re-published so the planner does not take the world for lost
                if now >= next_tick:
                    self.publish()
                    next_tick = now + self.opt.republish
                cmds = self.serve(max(0.0, min(next_tick - now, self.opt.republish)))
                if not self._paused:
                    next_tick = time.monotonic()
                continue
            if now >= next_tick:
                for robot in robots:
                    stale[robot] = self._watch(robot, now - latest_at[robot], stale[robot])
                fresh = not all(stale.values())
                ctrl, source = self.episode.playing() if fresh else (None, -1)
                newest = min(latest_at.values())
                cmd_age = now - newest if newest > -np.inf else None
                if ctrl is None and source >= 0 and source != ended:
                    ended = source
                    log.warning(
                        "the plan of state %d ran out at t=%.2f s: safe control until the next",
                        source,
                        self.world.time,
                    )
                    self.log.event("plan_ended", seq=source, time=self.world.time)
                self.step(ctrl, source, cmd_age=cmd_age)
                next_tick += period
                if now - next_tick > 10 * period:  # fell far behind (debugger, load): resync
                    next_tick = now
            cmds = self.serve(max(0.0, next_tick - time.monotonic()))

    def _watch(self, robot: str | None, age: float, was_stale: bool) -> bool:
        """Whether ``robot``'s planner (None: the planner) is quiet, its newest command ``age``
        s old: a change is logged, and a quiet planner's plans are dropped (its robot holds its
        safe control; a team's other robots play on)."""
        stale = age > self.opt.command_timeout
        named = {"robot": robot} if robot is not None else {}
        if not stale and was_stale:
            self.log.event("commands_fresh", seq=self.episode.seq, **named)
        elif stale and not was_stale:
            log.warning(
                "no command for %.2f s: holding the robot%s (safe control)",
                self.opt.command_timeout,
                f" {robot}" if robot is not None else "",
            )
            self.log.event("commands_stale", seq=self.episode.seq, age=age, **named)
            self.episode.drop_plans(robot)
        return stale

    def _outdated(self, cmd: P.Command) -> bool:
        """Whether ``cmd`` answers a state older than the command time-out (in world seconds):
        a command held up by the link (a cut, a queue) is dropped and logged, never played, and
        its lag is not published, or the planner would date every later plan that far ahead."""
        age = self.episode.state_age(cmd.seq)
        if age is None or age <= self.opt.command_timeout * self.opt.realtime_factor:
            return False
        log.warning("dropped a command answering state %d, %.2f s old", cmd.seq, age)
        self.log.event("stale_command", seq=cmd.seq, age=age, time=self.world.time)
        return True

    def _linger(self) -> None:
        end = time.monotonic() + self.opt.linger
        while time.monotonic() < end and not self._stop:
            self.publish()
            self.serve(0.05)

    # ------------------------------------------------------------------ steps

    def step(self, ctrl: np.ndarray | None, source: int = -1, cmd_age: float | None = None) -> None:
        """Real time: one logged world step (:meth:`Episode.apply`), then its state published."""
        self.episode.apply(ctrl, source, cmd_age)
        self._after_step()
        self.publish()

    def _after_step(self) -> None:
        if self.viewer is not None:
            self.viewer.sync()

    def publish(self) -> None:
        """The world's current state as state ``seq``. A state the world's link loses
        (:meth:`Episode.publish`) is not sent: lock-step re-sends it on the ``republish`` timer
        (the loss costs wall time, never world time), real time sends the next step's."""
        state = self.episode.publish()
        if state is not None:
            self.pub.send(P.encode(state, self.version))

    def serve(self, timeout_s: float) -> list[P.Command]:
        """Serve control requests and drain commands; return each robot's newest valid one (a
        team's planners answer the same state: one each)."""
        got = []
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
                    got.append(cmd)
        return list({c.robot: c for c in got}.values())

    def _accept_command(self, frame: bytes) -> P.Command | None:
        try:
            cmd = P.decode(frame, expect="command", versions=P.VERSIONS)
        except P.ProtocolError as exc:
            return self._reject(str(exc))
        if cmd.session != self.episode.session:
            return None  # for an earlier run of this server: silently outdated, not malformed
        team = [m.name for m in self.scenario.team]
        if team and cmd.robot not in team:
            return self._reject(
                f"command.robot is {cmd.robot!r}; this world's robots are {', '.join(team)}"
            )
        if not team and cmd.robot is not None:
            return self._reject(f"command.robot is {cmd.robot!r}; this world has one robot")
        nu = self._player_nu(cmd.robot)
        if cmd.ctrl.shape != (nu,):
            return self._reject(
                f"command.ctrl has shape {list(cmd.ctrl.shape)}, "
                f"the {'robot ' + repr(cmd.robot) if cmd.robot else 'model'} needs [{nu}]"
            )
        return cmd

    def _note_refusals(self) -> None:
        """Peers that security refused, into the episode log: a key outside the allow list
        (the ZAP thread already logged it with the peer's address), a peer without keys or one
        holding another world public key (logged here, from the socket monitors)."""
        found = [
            (f"key {r.key} from {r.address} is not in the allow list", True)
            for r in (self.auth.refusals() if self.auth else [])
        ]
        for name, m in self.monitors.items():
            for event, value in m.failures():
                if event != zmq.EVENT_HANDSHAKE_FAILED_AUTH:  # AUTH: the ZAP refusal above
                    found.append(
                        (
                            f"handshake on the {name} socket failed: "
                            f"{describe_handshake_failure(event, value)}",
                            False,
                        )
                    )
        for reason, logged in found:
            self._refused += 1
            sampled = self._refused <= 10 or self._refused % 100 == 0  # a peer retrying
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
            msg, version = P.decode_versioned(
                frame, expect=("hello", "control"), versions=P.VERSIONS
            )
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
            chosen = choose_version(msg, version)
        except P.ProtocolError as exc:
            reason = f"refused: {exc}"
            log.error(reason)
            self.log.event("handshake_refused", reason=reason)
            self.rep.send(P.encode(P.Error(reason=reason, versions=speaks)))
            return
        reason = self._robot_refusal(msg, chosen)
        if msg.scenario_hash != self.scenario.hash:
            reason = (
                f"scenario mismatch: the server runs {self.scenario.name!r} "
                f"(hash {self.scenario.hash}), the planner loaded {msg.scenario!r} "
                f"(hash {msg.scenario_hash}); start both with the same scenario file"
            )
        if reason is not None:
            log.error(reason)
            self.log.event("handshake_refused", reason=reason)
            self.rep.send(P.encode(P.Error(reason=reason, versions=speaks), chosen))
            return
        robot = {"robot": msg.robot} if msg.robot is not None else {}
        self.log.event("handshake", client=msg.client, version=chosen, **robot)
        log.info(
            "planner connected (%s, protocol version %d)%s",
            msg.client,
            chosen,
            f" for robot {msg.robot}" if msg.robot else "",
        )
        self.version = chosen
        self.rep.send(
            P.encode(
                P.Welcome(
                    scenario=self.scenario.name,
                    scenario_hash=self.scenario.hash,
                    mode=self.opt.mode,
                    dt=self.world.dt,
                    nu=self._player_nu(msg.robot),
                    session=self.episode.session,
                    seed=self.episode.seed if self.opt.keep_serving else None,
                ),
                chosen,
            )
        )
        self.publish()

    def _robot_refusal(self, hello: P.Hello, version: int) -> str | None:
        """Why a planner's ``hello.robot`` does not fit this world, or None: a team's world
        needs a robot of its team (protocol 4), a world of one robot none."""
        names = [m.name for m in self.scenario.team]
        if not names:
            if hello.robot is None:
                return None
            return (
                "refused: this world has one robot; start the planner without --robot "
                f"(got {hello.robot!r})"
            )
        if hello.robot in names and version >= 4:
            return None
        return (
            f"refused: this world drives the robots {', '.join(names)}: start a planner per "
            f"robot with --robot NAME (protocol 4), got {hello.robot!r} in version {version}"
        )

    def _player_nu(self, robot: str | None) -> int:
        """The length of ``command.ctrl`` from the planner of ``robot`` (None: the robot)."""
        if robot is None:
            return int(self.world.model.nu)
        return len(next(m for m in self.scenario.team if m.name == robot).robot.spec.ctrl_names)

    def _control(self, msg: P.Control) -> None:
        """A control op: echoed when done, answered with ``error`` and its reason when refused
        (an unknown or robot body to move); either way logged."""
        if msg.op == "move":
            try:
                self.episode.move(msg.object, msg.pos, msg.quat)
            except ValueError as exc:
                self.rep.send(P.encode(P.Error(reason=f"move refused: {exc}")))
                return
            # a new state: a lock-step world waits for the command answering the moved one
            self.publish()
        elif msg.op == "reset" and msg.seed is not None and not self.opt.keep_serving:
            reason = (
                "a reset with a seed begins a new episode, and this world serves one: "
                "start it with --keep-serving"
            )
            self.log.event("control_refused", op=msg.op, reason=reason)
            self.rep.send(P.encode(P.Error(reason=f"reset refused: {reason}")))
            return
        else:
            self.log.event(
                "control", op=msg.op, **({"seed": msg.seed} if msg.seed is not None else {})
            )
        if msg.op == "shutdown":
            self._stop = True
            self.episode.abort()
        elif (
            msg.op == "reset"
            and self.opt.keep_serving
            and (msg.seed is not None or self.episode.finished)
        ):
            # run() ends this episode and begins the seed's (after one: the same seed again)
            self._next_seed = self.episode.seed if msg.seed is None else msg.seed
        elif msg.op == "reset":
            # a new session: the planner starts over; plans dated in the old run are void
            self.episode.reset()  # the plans received go with the old session
            self.publish()
        elif msg.op in ("pause", "resume"):
            if self._paused != (msg.op == "pause"):
                log.info(
                    "world %s at t=%.2f s",
                    "paused" if msg.op == "pause" else "resumed",
                    self.world.time,
                )
            self._paused = msg.op == "pause"
            if self._paused:
                self.episode.stop_world()  # a robot must not go on with its last command
        self.rep.send(P.encode(msg))

    def close(self) -> None:
        if self.episode is not None:
            self.episode.world.close()
        for m in self.monitors.values():
            m.close()
        for s in (self.rep, self.pub, self.pull):
            s.close(0)
        if self.auth is not None:
            self.auth.stop()
        self.ctx.term()
