"""Push frames at a world's command socket: the soak's flood (:mod:`scripts.measure.soak_episodes`).

On loopback the soak calls :func:`push` itself; with ``--netns`` it starts this module once in
the planner's namespace (``python scripts/measure/push_frames.py ENDPOINT KEYS``, :func:`serve`)
and hands it each flood as a file (a msgpack list of byte strings), so that the garbage crosses
the link from where a planner sits, without a start-up's delay. With KEYS (the ``m3p2i keys``
folder) the socket is a CURVE client with the planner's key pair: a CURVE world refuses a socket
without keys at the handshake, so a flood without them would only test the refusal; with them
the garbage reaches the world's decoder, as from a compromised or buggy planner.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import msgpack
import zmq

from planner_client.keys import curve_client, load_planner_keys
from shared.endpoints import socket


def push(ctx: zmq.Context, endpoint: str, frames: list[bytes], keys: Path | None = None) -> int:
    """Send ``frames`` in order from a PUSH socket of our own (a CURVE client with the planner's
    keys when ``keys``); returns how many were sent. RuntimeError when the socket accepts none
    for 5 s (no connection, or the handshake refused)."""
    sock = socket(ctx, zmq.PUSH)
    if keys is not None:
        own = load_planner_keys(keys)
        curve_client(sock, own.own, own.world)
    sock.connect(endpoint)
    try:
        for fr in frames:
            if not sock.poll(5000, zmq.POLLOUT):
                raise RuntimeError(f"the world's command socket {endpoint} accepts no frames")
            sock.send(fr, zmq.NOBLOCK)
    finally:
        time.sleep(0.2)  # let the frames leave before the socket closes
        sock.close(0)
    return len(frames)


def serve(endpoint: str, keys: Path | None) -> int:
    """One flood per line read: the line is the path of a msgpack list of frames; each answered
    by a line ``sent N`` or ``error: WHY``. Started once, so that a flood costs no start-up."""
    ctx = zmq.Context()
    try:
        print("ready", flush=True)
        for line in sys.stdin:
            try:
                n = push(ctx, endpoint, msgpack.unpackb(Path(line.strip()).read_bytes()), keys)
                print(f"sent {n}", flush=True)
            except Exception as exc:  # reported to the soak, which fails the flood
                print(f"error: {exc}".replace("\n", " "), flush=True)
    finally:
        ctx.term()
    return 0


if __name__ == "__main__":
    sys.exit(serve(sys.argv[1], Path(sys.argv[2]) if len(sys.argv) > 2 else None))
