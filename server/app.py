"""The world server's network loop: handshake, state publishing, command intake, episode log.

Lock-step: state ``seq`` is published and the world waits for the command answering it (the
state is re-published every ``republish`` seconds meanwhile, for late subscribers). Real-time:
the world steps on the wall clock holding the latest command; a command older than
``command_timeout`` is replaced by the robot's safe control (zero velocity) until a fresh one
arrives. Bad messages are logged with their reason and dropped; nothing received is executed.
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
from shared.evaluation.metrics import MetricsEvaluator, describe, mean_hz
from shared.scenario import Scenario
from server.episode_log import EpisodeLog, read_log
from server.world import Outcome, SimWorld

log = logging.getLogger("m3p2i.server")


@dataclass
class ServerOptions:
    mode: str = "lockstep"            # lockstep | realtime
    command_timeout: float = 0.5      # realtime: seconds before a command is stale
    republish: float = 0.2            # lockstep: re-send the pending state this often
    linger: float = 0.5               # seconds to keep publishing the final state
    realtime_factor: float = 1.0      # realtime: simulated seconds per wall second
    wait_planner: float = 0.0         # seconds to wait for the first command; 0 = forever


class WorldServer:
    def __init__(self, scenario: Scenario, endpoints: Endpoints, log_path: Path,
                 options: ServerOptions | None = None, viewer=None, seed: int = 0):
        self.scenario = scenario
        self.opt = options or ServerOptions()
        self.world = SimWorld(scenario, seed)
        self.metrics = MetricsEvaluator(scenario, self.world.model)   # bad metric frames fail here
        self.session = secrets.token_hex(4)
        self.seq = 0
        self.viewer = viewer
        self.log = EpisodeLog(log_path)
        self.ctx = zmq.Context()
        self.rep = socket(self.ctx, zmq.REP)
        self.pub = socket(self.ctx, zmq.PUB)
        self.pull = socket(self.ctx, zmq.PULL)
        for s, addr in ((self.rep, endpoints.control), (self.pub, endpoints.state),
                        (self.pull, endpoints.command)):
            s.bind(addr)
        self.poller = zmq.Poller()
        self.poller.register(self.rep, zmq.POLLIN)
        self.poller.register(self.pull, zmq.POLLIN)
        self._plan_times: list[float] = []
        self._action = ""
        self.action_changes: list[tuple[float, str]] = []
        self._rejected = 0
        self._stop = False
        self.log.write("header", scenario=scenario.name, scenario_hash=scenario.hash,
                       source=scenario.source, mode=self.opt.mode, dt=self.world.dt,
                       session=self.session, nq=self.world.model.nq, nu=self.world.model.nu,
                       seed=seed, initial=self.world.initial)

    # ------------------------------------------------------------------ loop

    def run(self) -> Outcome:
        """Serve one episode; always closes the log with a summary, even on Ctrl-C."""
        log.info("serving %s (%s mode) on %s", self.scenario.name, self.opt.mode,
                 self.rep.getsockopt_string(zmq.LAST_ENDPOINT))
        try:
            if self.opt.mode == "lockstep":
                self._run_lockstep()
            else:
                self._run_realtime()
            self._linger()
        except KeyboardInterrupt:
            self.world.status = "stopped"
            log.info("interrupted")
        finally:
            outcome = self.world.outcome()
            hz = mean_hz(self._plan_times)
            metrics = self._episode_metrics(outcome.status)
            self.log.write("summary", status=outcome.status, time=outcome.time,
                           measures=outcome.measures, planner_hz=hz, steps=self.seq,
                           rejected=self._rejected, actions=self.action_changes,
                           metrics=metrics)
            self.log.close()
            self.close()
        outcome.measures["planner_hz"] = hz
        return outcome

    def _episode_metrics(self, status: str) -> dict | None:
        """shared.evaluation.metrics on the logged steps (the log is line-buffered, so complete on
        disk). A failure here is logged, never allowed to cost the summary record."""
        try:
            metrics = self.metrics.evaluate(read_log(self.log.path), status=status)
        except Exception:   # noqa: BLE001 - the summary must be written whatever went wrong
            log.exception("could not compute the episode metrics")
            return None
        log.info("metrics: %s", describe(metrics))
        return metrics.as_dict()

    def _running(self) -> bool:
        return self.world.status == "running" and not self._stop

    def _run_lockstep(self) -> None:
        self._publish()
        last_pub = started = time.monotonic()
        while self._running():
            cmd = self._poll(self.opt.republish)
            if cmd is not None and cmd.seq == self.seq:
                self._apply(cmd)
                last_pub = time.monotonic()
            elif time.monotonic() - last_pub >= self.opt.republish:
                if self.seq == 0 and self.opt.wait_planner and \
                        time.monotonic() - started > self.opt.wait_planner:
                    raise TimeoutError(f"no planner command within {self.opt.wait_planner} s")
                self._publish()
                last_pub = time.monotonic()

    def _run_realtime(self) -> None:
        period = self.world.dt / self.opt.realtime_factor
        latest: P.Command | None = None
        latest_at = -np.inf
        stale = True
        next_tick = time.monotonic()
        self._publish()
        while self._running():
            cmd = self._poll(max(0.0, next_tick - time.monotonic()))
            if cmd is not None:
                latest, latest_at = cmd, time.monotonic()
            now = time.monotonic()
            if now < next_tick:
                continue
            fresh = latest is not None and now - latest_at <= self.opt.command_timeout
            if fresh and stale:
                self.log.event("commands_fresh", seq=self.seq)
            elif not fresh and not stale and latest is not None:
                log.warning("no command for %.2f s: holding the robot (safe control)",
                            self.opt.command_timeout)
                self.log.event("commands_stale", seq=self.seq, age=now - latest_at)
            stale = not fresh
            self._apply(latest if fresh else None)
            next_tick += period
            if now - next_tick > 10 * period:   # fell far behind (debugger, load): resync
                next_tick = now

    def _linger(self) -> None:
        end = time.monotonic() + self.opt.linger
        while time.monotonic() < end and not self._stop:
            self._publish()
            self._poll(0.05)

    # ------------------------------------------------------------------ steps

    def _apply(self, cmd: P.Command | None) -> None:
        ctrl = self.world.safe_command() if cmd is None else cmd.ctrl
        self.world.step(ctrl)
        for event in self.world.events:
            log.info("disturbance: %s moved at t=%.2f s", event["object"], event["time"])
            self.log.event("disturbance", **event)
        self.world.events.clear()
        self.seq += 1
        if cmd is not None and cmd.plan_time > 0:
            self._plan_times.append(cmd.plan_time)
        if cmd is not None and cmd.action != self._action:
            self._action = cmd.action
            self.action_changes.append((float(self.world.data.time), cmd.action))
            self.log.event("action", time=float(self.world.data.time), action=cmd.action)
        d = self.world.data
        self.log.write("step", seq=self.seq, time=float(d.time), qpos=d.qpos, qvel=d.qvel,
                       act=d.act, mocap_pos=d.mocap_pos, mocap_quat=d.mocap_quat, ctrl=d.ctrl,
                       action=cmd.action if cmd else "", safe=cmd is None,
                       plan_time=cmd.plan_time if cmd else 0.0, extras=self.world.extras)
        if self.viewer is not None:
            self.viewer.sync()
        self._publish()

    def _publish(self) -> None:
        self.pub.send(P.encode(self.world.state(self.session, self.seq)))

    def _poll(self, timeout_s: float) -> P.Command | None:
        """Serve control requests and drain commands; return the newest valid command."""
        newest = None
        events = dict(self.poller.poll(int(timeout_s * 1000)))
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
            cmd = P.decode(frame, expect="command")
        except P.ProtocolError as exc:
            return self._reject(str(exc))
        if cmd.session != self.session:
            return None   # for an earlier run of this server: silently outdated, not malformed
        if cmd.ctrl.shape != (self.world.model.nu,):
            return self._reject(f"command.ctrl has shape {list(cmd.ctrl.shape)}, "
                                f"the model needs [{self.world.model.nu}]")
        return cmd

    def _reject(self, reason: str) -> None:
        self._rejected += 1
        if self._rejected <= 10 or self._rejected % 100 == 0:
            log.warning("rejected message (%d so far): %s", self._rejected, reason)
        self.log.event("rejected", reason=reason)
        return None

    def _serve_control(self) -> None:
        frame = self.rep.recv()
        try:
            msg = P.decode(frame, expect=("hello", "control"))
        except P.ProtocolError as exc:
            self._reject(str(exc))
            self.rep.send(P.encode(P.Error(reason=f"refused: {exc}")))
            return
        if isinstance(msg, P.Control):
            self.log.event("control", op=msg.op)
            if msg.op == "shutdown":
                self._stop = True
                self.world.status = "stopped"
            elif msg.op == "reset":
                self.world.reset()
                self.seq += 1
                self._publish()
            self.rep.send(P.encode(msg))
            return
        if msg.scenario_hash != self.scenario.hash:
            reason = (f"scenario mismatch: the server runs {self.scenario.name!r} "
                      f"(hash {self.scenario.hash}), the planner loaded {msg.scenario!r} "
                      f"(hash {msg.scenario_hash}); start both with the same scenario file")
            log.error(reason)
            self.log.event("handshake_refused", reason=reason)
            self.rep.send(P.encode(P.Error(reason=reason)))
            return
        self.log.event("handshake", client=msg.client)
        log.info("planner connected (%s)", msg.client)
        self.rep.send(P.encode(P.Welcome(
            scenario=self.scenario.name, scenario_hash=self.scenario.hash, mode=self.opt.mode,
            dt=self.world.dt, nu=int(self.world.model.nu), session=self.session)))
        self._publish()

    def close(self) -> None:
        for s in (self.rep, self.pub, self.pull):
            s.close(0)
        self.ctx.term()
