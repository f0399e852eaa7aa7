"""Protocol version negotiation (docs/protocol.md, "Version negotiation"): the planner offers the
versions it speaks, the world answers in the highest both speak; a version-1 world (commands
without plans, held) is still served, and a world of an unknown version is refused clearly."""

from __future__ import annotations

import logging
import threading
import time
from typing import ClassVar

import msgpack
import numpy as np
import pytest
import zmq

from m3p2i.launch import free_port_block
from planner_client.build import build_motion_planner, build_parts
from planner_client.controller import Controller
from planner_client.loop import HandshakeRefused, PlannerClient
from planner_client.task import FixedModes
from server.app import choose_version
from server.world import SimWorld
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from tests.helpers import start_server, stop


@pytest.fixture(scope="module")
def nav():
    return load_scenario("navigation")


@pytest.fixture(scope="module")
def planner(nav):
    return build_motion_planner(nav, threads=2)


def _client(planner, nav, port: int) -> PlannerClient:
    client = PlannerClient(
        Controller(build_parts(planner, FixedModes(("navigate",)))),
        Endpoints(port=port),
        nav.name,
        nav.hash,
        diagnostics=False,
    )
    return client


def _close(client: PlannerClient) -> None:
    for s in (client.sub, client.push):
        s.close(0)
    client.ctx.term()  # the module's planner is shared: not closed here


# ------------------------------------------------------------------ unit


def test_version_1_frames_lack_what_version_2_added():
    cmd = P.Command(
        session="s", seq=1, ctrl=np.zeros(2), plan_ctrl=np.ones((3, 2)), plan_t0=0.5, plan_dt=0.05
    )
    raw = msgpack.unpackb(P.encode(cmd, 1))
    assert raw["v"] == 1 and set(raw) == {
        "type",
        "v",
        "session",
        "seq",
        "ctrl",
        "plan_time",
        "action",
    }
    back, version = P.decode_versioned(P.encode(cmd, 1), versions=P.VERSIONS)
    assert version == 1 and not back.has_plan
    with pytest.raises(P.ProtocolError, match="protocol version 1 not supported"):
        P.decode(P.encode(cmd, 1))  # the default reads the newest only
    state = P.State(
        session="s",
        seq=0,
        time=0.0,
        qpos=np.zeros(2),
        qvel=np.zeros(2),
        act=np.zeros(0),
        mocap_pos=np.zeros((0, 3)),
        mocap_quat=np.zeros((0, 4)),
        lag=0.2,
    )
    assert "lag" not in msgpack.unpackb(P.encode(state, 1))


def test_the_anytime_planners_samples_travel_in_version_3_only():
    cmd = P.Command(session="s", seq=1, ctrl=np.zeros(2), samples=120)
    assert P.decode(P.encode(cmd)).samples == 120
    raw = msgpack.unpackb(P.encode(cmd, 2))
    assert "samples" not in raw
    assert P.decode_versioned(P.encode(cmd, 2), versions=P.VERSIONS)[0].samples is None
    bad = msgpack.unpackb(P.encode(cmd))
    bad["samples"] = 1.5
    with pytest.raises(P.ProtocolError, match=r"command\.samples: expected an integer"):
        P.decode(msgpack.packb(bad))


def test_the_world_chooses_the_highest_common_version():
    hello = P.Hello(scenario="n", scenario_hash="h", versions=[1, 2])
    assert choose_version(hello, 1) == 2
    assert choose_version(P.Hello(scenario="n", scenario_hash="h", versions=[1]), 1) == 1
    assert choose_version(P.Hello(scenario="n", scenario_hash="h"), 2) == 2  # no offer: its v
    assert choose_version(P.Hello(scenario="n", scenario_hash="h", versions=[1, 2, 3]), 1) == 3
    with pytest.raises(
        P.ProtocolError,
        match="the planner speaks versions 5, 9, this world speaks versions 1, 2, 3, 4",
    ):
        choose_version(P.Hello(scenario="n", scenario_hash="h", versions=[5, 9]), 1)


def test_a_hello_of_an_unknown_version_offering_versions_names_both_sides():
    frame = msgpack.packb(
        {"type": "hello", "v": 9, "scenario": "n", "scenario_hash": "h", "versions": [9]}
    )
    with pytest.raises(
        P.ProtocolError,
        match="no common protocol version: the peer speaks "
        "version 9, this side speaks versions 1, 2, 3, 4",
    ):
        P.decode(frame, versions=P.VERSIONS)


def test_a_hello_of_an_unknown_version_offering_a_common_one_is_refused_for_its_v():
    # the offer is fine (2 is common): the frame's own v is what is wrong, and the reason
    # must not claim that no version is common
    frame = msgpack.packb(
        {"type": "hello", "v": 9, "scenario": "n", "scenario_hash": "h", "versions": [2]}
    )
    with pytest.raises(P.ProtocolError) as info:
        P.decode(frame, versions=P.VERSIONS)
    reason = str(info.value)
    assert "hello written in protocol version 9, which this side does not read" in reason
    assert "no common protocol version" not in reason


# ------------------------------------------------------------------ a current world


def test_negotiation_with_a_current_world(nav, planner, tmp_path):
    port = free_port_block()
    server = start_server("navigation", port, tmp_path / "log.jsonl")
    ctx = zmq.Context()
    client = _client(planner, nav, port)
    try:
        welcome = client.handshake(give_up=60)
        assert client.version == 4 and welcome.session

        def ask(**hello):
            req = ctx.socket(zmq.REQ)
            req.setsockopt(zmq.LINGER, 0)
            req.connect(Endpoints(port=port).control)
            req.send(
                msgpack.packb(
                    {"type": "hello", "scenario": nav.name, "scenario_hash": nav.hash, **hello}
                )
            )
            assert req.poll(30000)
            frame = req.recv()
            req.close()
            return msgpack.unpackb(frame), P.decode_versioned(frame, versions=P.VERSIONS)

        raw, (reply, version) = ask(v=1, versions=[1])  # a planner speaking 1 only
        assert raw["type"] == "welcome" and version == 1 and "seed" not in raw
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.setsockopt(zmq.LINGER, 0)
        sub.connect(Endpoints(port=port).state)
        assert sub.poll(10000)  # re-published every 0.2 s in lock-step
        state = msgpack.unpackb(sub.recv())
        assert state["v"] == 1 and "lag" not in state
        sub.close()
        raw, (reply, version) = ask(v=2)  # a planner from before the negotiation
        assert raw["type"] == "welcome" and version == 2
        raw, (reply, version) = ask(v=1, versions=[1, 2])  # a version-2 planner
        assert raw["type"] == "welcome" and version == 2
        raw, (reply, version) = ask(v=1, versions=[9])
        assert isinstance(reply, P.Error) and reply.versions == [1, 2, 3, 4]
        assert "the planner speaks version 9, this world speaks versions 1, 2, 3" in reply.reason
    finally:
        _close(client)
        ctx.term()
        stop(server)


# ------------------------------------------------------------------ fake old or unknown worlds


class FakeWorld:
    """A world written by hand in msgpack, as a bridge of another protocol version would be:
    ``version`` 1 reads exactly what version 1 read (anything else is refused with its error,
    as that world did), publishes version-1 states and takes only version-1 commands."""

    V1_HELLO: ClassVar[set[str]] = {"type", "v", "scenario", "scenario_hash", "client"}
    V1_COMMAND: ClassVar[set[str]] = {"type", "v", "session", "seq", "ctrl", "plan_time", "action"}

    def __init__(self, nav, version: int, answer: str = "welcome"):
        self.nav, self.version, self.answer = nav, version, answer
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
        world.reset()
        self.start = world.state()
        self.nu = int(world.model.nu)
        self.hellos: list[dict] = []  # every hello, and whether it was accepted
        self.commands: list[dict] = []
        self.refused: list[str] = []
        self.welcomed = False
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _frame(self, **fields) -> bytes:
        return msgpack.packb({"v": self.version, **fields}, use_bin_type=True)

    def _serve(self) -> None:
        seq, next_pub = 0, time.monotonic()
        poller = zmq.Poller()
        poller.register(self.rep, zmq.POLLIN)
        poller.register(self.pull, zmq.POLLIN)
        while not self._stop.is_set():
            events = dict(poller.poll(10))
            if self.rep in events:
                self._hello(msgpack.unpackb(self.rep.recv()))
            if self.pull in events:
                self._command(msgpack.unpackb(self.pull.recv()))
            if self.welcomed and time.monotonic() >= next_pub:
                seq += 1
                s = self.start
                self.pub.send(
                    self._frame(
                        type="state",
                        session="old",
                        seq=seq,
                        time=0.05 * seq,
                        **{
                            k: P.encode_array(getattr(s, k))
                            for k in ("qpos", "qvel", "act", "mocap_pos", "mocap_quat")
                        },
                    )
                )
                next_pub = time.monotonic() + 0.02

    def _hello(self, hello: dict) -> None:
        ok = (
            hello.get("v") == 1 and set(hello) <= self.V1_HELLO
            if self.version == 1
            else self.answer == "welcome"
        )  # version 9: welcome or refuse any hello
        self.hellos.append({**hello, "accepted": ok})
        if not ok:
            reason = (
                f"refused: protocol version {hello.get('v')!r} not supported (this side "
                f"speaks version {self.version})"
                if hello.get("v") != self.version
                else f"refused: hello: unknown field(s) {sorted(set(hello) - self.V1_HELLO)}"
            )
            self.rep.send(self._frame(type="error", reason=reason))
            return
        self.rep.send(
            self._frame(
                type="welcome",
                scenario=self.nav.name,
                scenario_hash=self.nav.hash,
                mode="realtime",
                dt=0.05,
                nu=self.nu,
                session="old",
            )
        )
        self.welcomed = True

    def _command(self, cmd: dict) -> None:
        ctrl = cmd.get("ctrl")
        if (
            cmd.get("v") != 1
            or set(cmd) - self.V1_COMMAND
            or not isinstance(ctrl, dict)
            or ctrl.get("shape") != [self.nu]
            or cmd.get("session") != "old"
        ):
            self.refused.append(str(cmd))
            return
        self.commands.append(cmd)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for s in (self.rep, self.pub, self.pull):
            s.close(0)
        self.ctx.term()


def test_a_version_1_world_is_served_with_one_warning(nav, planner, caplog):
    world = FakeWorld(nav, version=1)
    client = _client(planner, nav, world.port)
    try:
        with caplog.at_level(logging.INFO, logger="m3p2i.planner"):
            client.run(max_iterations=8)
            client.handshake(give_up=10)  # a reconnection: no second warning
        assert client.version == 1
        # the offer (hello v1 + versions) is refused by the strict old world, the plain one not
        assert [h["accepted"] for h in world.hellos] == [False, True, False, True]
        assert world.hellos[0]["versions"] == [1, 2, 3, 4] and "versions" not in world.hellos[1]
        time.sleep(0.2)
        assert len(world.commands) >= 8 and not world.refused, world.refused[:2]
        assert all(c["v"] == 1 for c in world.commands)
        warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert len(warnings) == 1 and "protocol version 1 only" in warnings[0], warnings
        assert "holds each command's ctrl" in warnings[0]
    finally:
        _close(client)
        world.close()


@pytest.mark.parametrize(
    "answer, reason",
    [
        ("welcome", "protocol version 9 not supported (this side speaks versions 1, 2, 3, 4)"),
        ("error", "the world speaks protocol version 9, this planner speaks versions 1, 2, 3"),
    ],
)
def test_a_world_of_an_unknown_version_is_refused_with_the_reason(nav, planner, answer, reason):
    world = FakeWorld(nav, version=9, answer=answer)
    client = _client(planner, nav, world.port)
    try:
        with pytest.raises(HandshakeRefused) as info:
            client.handshake(give_up=10)
        assert reason in str(info.value)
        assert len(world.hellos) == 1  # no retry in another form
    finally:
        _close(client)
        world.close()
