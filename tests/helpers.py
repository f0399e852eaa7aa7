"""Test helpers: start the two processes on free loopback ports and watch the world's state."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import zmq

from m3p2i.cli import free_port_block
from m3p2i.launch import stop_processes
from planner_client.keys import PlannerKeys, curve_client
from shared import protocol as P
from shared.endpoints import Endpoints

ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def _sigint_as_in_a_terminal() -> None:
    # a test run started in the background (`pytest &`, some CI runners) hands its children
    # SIGINT ignored, and Python then installs no KeyboardInterrupt: Ctrl-C tests need it back
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_server(scenario: str, port: int, log: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "server",
            "--scenario",
            scenario,
            "--port",
            str(port),
            "--log",
            str(log),
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
        preexec_fn=_sigint_as_in_a_terminal,
    )


def start_planner(scenario: str, port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "planner_client",
            "--scenario",
            scenario,
            "--port",
            str(port),
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
        preexec_fn=_sigint_as_in_a_terminal,
    )


def wait_episode(
    server: subprocess.Popen, planner: subprocess.Popen, timeout: float = 300.0, grace: float = 10.0
) -> str:
    """The server's output once its episode is over. In lock-step a world whose planner died
    waits for it for ever: a planner gone for ``grace`` seconds while the server still runs
    raises at once, with the planner's output, instead of after ``timeout``."""
    deadline = time.monotonic() + timeout
    gone = None
    while True:
        try:
            return server.communicate(timeout=0.5)[0]
        except subprocess.TimeoutExpired:
            now = time.monotonic()
            if planner.poll() is not None:
                gone = gone or now
                if now - gone > grace:
                    raise AssertionError(
                        f"the planner exited (code {planner.returncode}) while "
                        f"the episode ran:\n{planner.communicate()[0]}"
                    ) from None
            if now > deadline:
                raise


def stop(*procs: subprocess.Popen) -> None:
    stop_processes(procs)


class StateWatcher:
    """Subscribes to the world's state stream like a planner would (without commanding);
    with ``keys``, over CURVE with the planner's key pair."""

    def __init__(self, port: int, keys: PlannerKeys | None = None):
        self.keys = keys
        self.ctx = zmq.Context()
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.setsockopt(zmq.CONFLATE, 1)
        self._secure(self.sub)
        self.sub.connect(Endpoints(port=port).state)

    def _secure(self, sock: zmq.Socket) -> None:
        if self.keys is not None:
            curve_client(sock, self.keys.own, self.keys.world)

    def latest(self, timeout: float = 30.0) -> P.State:
        if not self.sub.poll(int(timeout * 1000)):
            raise TimeoutError("no state received")
        return P.decode(self.sub.recv(), expect="state")

    def control(self, port: int, op: str) -> None:
        req = self.ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        self._secure(req)
        req.connect(Endpoints(port=port).control)
        req.send(P.encode(P.Control(op=op)))
        req.poll(2000)
        req.close()

    def close(self) -> None:
        self.sub.close(0)
        self.ctx.term()


def wait_until(predicate, timeout: float, period: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return False


__all__ = [
    "StateWatcher",
    "free_port_block",
    "start_planner",
    "start_server",
    "stop",
    "wait_episode",
    "wait_until",
]


def play(controller, episode, steps: int) -> P.State:
    """``steps`` lock-step iterations of ``controller`` on the in-process ``episode``
    (server.inprocess) from its current state; the state after the last."""
    state = episode.publish()
    for _ in range(steps):
        episode.play(controller.step(state))
        state = episode.publish()
    return state
