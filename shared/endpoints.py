"""Socket addresses. The server binds three consecutive ports from ``port``; the planner binds
the fourth for diagnostics. Loopback by default: opening to a network is an explicit choice."""

from __future__ import annotations

from dataclasses import dataclass

import zmq

from shared.protocol import MAX_MESSAGE_BYTES

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 5555


@dataclass(frozen=True)
class Endpoints:
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT

    def _at(self, offset: int) -> str:
        return f"tcp://{self.host}:{self.port + offset}"

    @property
    def control(self) -> str:  # REP on the server: hello -> welcome | error; control ops
        return self._at(0)

    @property
    def state(self) -> str:  # PUB on the server: state
        return self._at(1)

    @property
    def command(self) -> str:  # PULL on the server: command
        return self._at(2)

    @property
    def diagnostics(self) -> str:  # PUB on the planner: diagnostics
        return self._at(3)


def socket(ctx: zmq.Context, kind: int, *, conflate: bool = False) -> zmq.Socket:
    """A socket with the project's safety defaults: size limit, no linger, optional conflate."""
    s = ctx.socket(kind)
    s.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
    s.setsockopt(zmq.LINGER, 0)
    if conflate:
        s.setsockopt(zmq.CONFLATE, 1)
    return s
