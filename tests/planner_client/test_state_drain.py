"""The planner's state socket in real time: a planner slower than the world plans on the newest
state, and the sensor readings of the states it overtook still reach its map (each reading
travels with one state only), once each, oldest first."""

from __future__ import annotations

import math
import time
import types

import numpy as np
import zmq

from planner_client.loop import PlannerClient
from shared import protocol as P
from shared.endpoints import socket
from shared.scans import Scan


def _scan(t: float) -> Scan:
    return Scan(
        name="lidar",
        kind="lidar",
        time=t,
        pos=np.zeros(3),
        quat=np.array([1.0, 0.0, 0.0, 0.0]),
        ranges=np.full(8, 2.0),
        range_min=0.05,
        range_max=6.0,
        angle_min=-math.pi,
        angle_increment=math.pi / 4,
    )


def _state(seq: int, scans: list[Scan], session: str = "s1") -> bytes:
    return P.encode(
        P.State(
            session=session,
            seq=seq,
            time=0.01 * seq,
            qpos=np.zeros(2),
            qvel=np.zeros(2),
            act=np.zeros(0),
            mocap_pos=np.zeros((0, 3)),
            mocap_quat=np.zeros((0, 4)),
            scans=scans,
        )
    )


def _client(answered):
    """The loop's receiving half on a loopback SUB, and the world's PUB feeding it."""
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    sub = socket(ctx, zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(f"tcp://127.0.0.1:{port}")
    client = types.SimpleNamespace(sub=sub, _answered=answered, dropped_states=0)
    for _ in range(100):  # the subscription reaches the publisher (slow joiner): 1 s at most
        pub.send(_state(0, []))
        if sub.poll(10):
            while sub.poll(0):
                sub.recv()
            break
    return ctx, pub, sub, client


def _wait_for(sub) -> None:
    """Until the burst is in the socket: loopback delivers in well under a millisecond."""
    sub.poll(2000)
    time.sleep(0.3)


def test_the_newest_state_carries_the_readings_of_those_it_overtook():
    ctx, pub, sub, client = _client(answered=("s1", 2))
    try:
        pub.send(_state(2, [_scan(0.02)]))  # answered already: its reading was fused
        pub.send(_state(3, [_scan(0.03)]))
        pub.send(_state(4, []))
        pub.send(_state(4, []))  # re-published
        pub.send(b"\x00not msgpack")
        pub.send(_state(5, [_scan(0.05)]))
        _wait_for(sub)
        state = PlannerClient._newest(client)
        assert state.seq == 5
        assert [s.time for s in state.scans] == [0.03, 0.05]
        assert client.dropped_states == 1
        assert PlannerClient._newest(client) is None  # drained
    finally:
        ctx.destroy(linger=0)


def test_a_republished_state_does_not_repeat_its_readings():
    ctx, pub, sub, client = _client(answered=None)
    try:
        pub.send(_state(7, [_scan(0.07)]))
        pub.send(_state(7, [_scan(0.07)]))  # a lock-step world re-publishing seq 7
        _wait_for(sub)
        state = PlannerClient._newest(client)
        assert state.seq == 7 and [s.time for s in state.scans] == [0.07]
    finally:
        ctx.destroy(linger=0)
