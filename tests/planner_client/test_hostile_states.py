"""States a hostile (or broken) world sends after a good handshake, at float64's edges but
finite, so that only their meaning is wrong: a ``time`` of 1e300 is refused by the decoder and
counted, and the planner answers the next good state; a ``qpos`` of 1e308 is planned from (MuJoCo
resets its rollouts), with MuJoCo's "Nan, Inf or huge value" warning said once in the log and
counted instead of printed for every sample."""

from __future__ import annotations

import dataclasses
import logging
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import zmq

from m3p2i.launch import free_port_block
from planner_client.build import build_motion_planner, build_parts
from planner_client.controller import Controller
from planner_client.loop import PlannerClient
from planner_client.task import FixedModes
from server.world import SimWorld
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from tests.helpers import ENV


@pytest.fixture(scope="module")
def nav():
    return load_scenario("navigation")


class ScriptedWorld:
    """A lock-step world in a thread that welcomes any hello and publishes a script of states,
    each re-published every 20 ms until its ``until`` holds (by default: a command answering it
    arrived), then the next; after the last it stops publishing. ``answered`` holds the seqs of
    the commands received."""

    def __init__(self, nav, script: list[tuple[P.State, Callable[[], bool] | None]]):
        self.port = free_port_block()
        ends = Endpoints(port=self.port)
        self.ctx = zmq.Context()
        self.rep, self.pub, self.pull = (self.ctx.socket(k) for k in (zmq.REP, zmq.PUB, zmq.PULL))
        for s, addr in (
            (self.rep, ends.control),
            (self.pub, ends.state),
            (self.pull, ends.command),
        ):
            s.setsockopt(zmq.LINGER, 0)
            s.bind(addr)
        world = SimWorld(nav, 0)
        self.welcome = P.Welcome(
            scenario=nav.name,
            scenario_hash=nav.hash,
            mode="lockstep",
            dt=float(world.model.opt.timestep),
            nu=int(world.model.nu),
            session="s1",
        )
        self.script = script
        self.answered: list[int] = []
        self.done = threading.Event()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self, deadline: float = 120.0) -> None:
        end = time.monotonic() + deadline
        poller = zmq.Poller()
        poller.register(self.rep, zmq.POLLIN)
        poller.register(self.pull, zmq.POLLIN)
        step, welcomed, next_pub = 0, False, 0.0
        while not self._stop.is_set() and time.monotonic() < end and step < len(self.script):
            events = dict(poller.poll(10))
            if self.rep in events:
                self.rep.recv()
                self.rep.send(P.encode(self.welcome))
                welcomed = True
            if self.pull in events:
                cmd = P.decode(self.pull.recv(), expect="command", versions=P.VERSIONS)
                self.answered.append(cmd.seq)
            if not welcomed:
                continue
            state, until = self.script[step]
            held = until() if until is not None else state.seq in self.answered
            if held:
                step += 1
                continue
            if time.monotonic() >= next_pub:
                self.pub.send(P.encode(state))
                next_pub = time.monotonic() + 0.02
        self.done.set()

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for s in (self.rep, self.pub, self.pull):
            s.close(0)
        self.ctx.term()


def _states(nav):
    """``state(seq, **fields)``: the navigation start, at world time seq x 0.05 s."""
    world = SimWorld(nav, 0)
    world.reset()
    start = world.state()

    def state(seq: int, **fields) -> P.State:
        base = {name: getattr(start, name) for name in ("qpos", "qvel", "act")}
        base |= {name: getattr(start, name) for name in ("mocap_pos", "mocap_quat")}
        return dataclasses.replace(
            P.State(session="s1", seq=seq, time=0.05 * seq, **base), **fields
        )

    return state


def test_the_decoder_refuses_a_state_time_off_any_world_clock():
    arrays = {name: np.zeros(2) for name in ("qpos", "qvel")}
    empty = {"act": np.zeros(0), "mocap_pos": np.zeros((0, 3)), "mocap_quat": np.zeros((0, 4))}
    for bad in (1e300, P.MAX_WORLD_TIME * 2, -1.0):
        frame = P.encode(P.State(session="s", seq=1, time=bad, **arrays, **empty))
        with pytest.raises(P.ProtocolError, match=r"state\.time: .* \(expected world seconds"):
            P.decode(frame, expect="state")
    good = P.encode(P.State(session="s", seq=1, time=P.MAX_WORLD_TIME, **arrays, **empty))
    assert P.decode(good, expect="state").time == P.MAX_WORLD_TIME


def test_a_warm_start_shifted_past_the_horizon_holds_its_end():
    import torch

    from planner_client.mppi.shift import shift

    seq = torch.arange(8.0).reshape(1, 8, 1)
    assert torch.equal(shift(seq, 1e300), shift(seq, 8))  # every step the last one
    assert shift(seq, 1e300)[0, :, 0].tolist() == [7.0] * 8
    assert torch.equal(shift(seq, -1e300), shift(seq, -8))  # every step the first one
    with pytest.raises(ValueError, match="finite"):
        shift(seq, float("inf"))


@pytest.mark.timeout(240)
def test_a_state_time_of_1e300_is_dropped_counted_and_the_next_state_answered(nav, caplog):
    state = _states(nav)
    client = None
    script = [
        (state(1), None),
        # dropped, never answered: on to the next once the planner counted it
        (state(2, time=1e300), lambda: getattr(client, "dropped_states", 0) >= 1),
        (state(3), None),
    ]
    world = ScriptedWorld(nav, script)
    client = PlannerClient(
        Controller(build_parts(build_motion_planner(nav, threads=2), FixedModes(("navigate",)))),
        Endpoints(port=world.port),
        nav.name,
        nav.hash,
        diagnostics=False,
    )
    try:
        with caplog.at_level(logging.WARNING, logger="m3p2i.planner"):
            stats = client.run(max_iterations=2)
        assert stats.iterations == 2
        assert world.done.wait(30) and world.answered[:1] == [1] and 3 in world.answered
        assert 2 not in world.answered and client.dropped_states >= 1
        assert any(
            "dropped a bad state message (1 so far): state.time: 1e+300 s" in m
            for m in caplog.messages
        ), caplog.messages
    finally:
        client.close()
        world.close()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_huge_qpos_makes_mujoco_warn_once_in_the_planners_log(nav):
    state = _states(nav)
    huge = state(1).qpos.copy()
    huge[0] = 1e308
    script = [
        (state(1), None),
        *((state(seq, qpos=huge), None) for seq in (2, 3, 4)),  # planned from: answered
        (state(5), None),
        (state(6, status="success"), lambda: False),  # the planner exits on it
    ]
    world = ScriptedWorld(nav, script)
    planner = subprocess.Popen(
        [sys.executable, "-m", "planner_client", "--scenario", "navigation"]
        + ["--port", str(world.port), "--threads", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )
    try:
        out, _ = planner.communicate(timeout=240)
    finally:
        if planner.poll() is None:
            planner.kill()
            planner.communicate()
        world.close()
    assert planner.returncode == 0, out
    assert {2, 3, 4, 5} <= set(world.answered), (world.answered, out)
    said = [line for line in out.splitlines() if "Nan, Inf or huge value" in line]
    first = [line for line in said if "said once" in line]
    assert len(first) == 1 and "MuJoCo: Nan, Inf or huge value in QPOS at DOF 0" in first[0], out
    # the rest are counts at powers of ten, never the warning again line by line
    assert all("MuJoCo warned" in line and "times so far" in line for line in said[1:]), said
    assert len(said) < 6, said
    assert "MuJoCo warnings" in out.splitlines()[-1], out
