"""Two hosts on one machine: two network namespaces joined by a veth pair, for the world and the
planner to talk over a real link that can be cut (``tests/scripts/test_netns.py``, ``scripts/soak.py
--netns``).

:func:`two_hosts` makes the namespaces ``world`` (``10.a.b.1``) and ``planner`` (``10.a.b.2``),
the pair between them and loopback in each, and always removes them: at the ``with`` block's end
whatever happens (an exception, Ctrl-C), and at interpreter exit should the block be left some
other way. Deleting a namespace takes its end of the pair, and so the pair, with it.

Needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN) and iproute2's ``ip``; where either is missing, or
``ip netns add`` is refused, :class:`Unavailable` says why.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass

_made = itertools.count()


class Unavailable(RuntimeError):
    """Network namespaces cannot be made here; the message says why."""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)
    if check and done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")
    return done


def unavailable() -> str | None:
    """Why namespaces cannot be made here (no ``ip``, not root), or None."""
    if shutil.which("ip") is None:
        return "network namespaces need iproute2's `ip` command, which is not installed"
    if os.geteuid() != 0:
        return (
            "network namespaces need root (CAP_SYS_ADMIN and CAP_NET_ADMIN); "
            f"this runs as uid {os.geteuid()}"
        )
    return None


@dataclass
class Hosts:
    """The two namespaces, the world's end of the pair (the one cut) and both addresses."""

    world_ns: str
    planner_ns: str
    world_if: str
    planner_if: str
    world_ip: str
    planner_ip: str

    def in_namespace(self, side: str, cmd: list[str]) -> list[str]:
        """The command line that runs ``cmd`` in the ``world`` or ``planner`` namespace (``ip
        netns exec`` replaces itself with the command: the process id is the command's, so
        signals reach it directly)."""
        ns = {"world": self.world_ns, "planner": self.planner_ns}[side]
        return ["ip", "netns", "exec", ns, *cmd]

    def link(self, up: bool) -> float:
        """Set the world's end of the pair up or down (the peer loses its carrier with it);
        returns the wall time just after."""
        _ip("-n", self.world_ns, "link", "set", self.world_if, "up" if up else "down")
        return time.time()

    def cut(self, seconds: float, wait=time.sleep) -> tuple[float, float]:
        """The link down for ``seconds`` (``wait(seconds)`` meanwhile), then up again, up
        whatever ``wait`` raises; returns the wall times of the cut and of the return."""
        down = self.link(up=False)
        try:
            wait(seconds)
        finally:
            up = self.link(up=True)
        return down, up


@contextlib.contextmanager
def two_hosts() -> Iterator[Hosts]:
    """Two namespaces joined by a veth pair, loopback up in each; removed at the end (and at
    exit, should the generator never be closed). :class:`Unavailable` where not permitted."""
    reason = unavailable()
    if reason:
        raise Unavailable(reason)
    tag = f"m3n{os.getpid() % 100000}{next(_made) % 10}"  # interface names: 15 bytes at most
    world_ns, planner_ns = f"{tag}w", f"{tag}p"
    world_if, planner_if = f"{tag}a", f"{tag}b"
    subnet = f"10.{200 + os.getpid() % 50}.{(os.getpid() + next(_made)) % 250}"
    made: list[str] = []

    def remove() -> None:
        while made:
            _ip("netns", "del", made.pop(), check=False)  # takes its end of the pair with it
        _ip("link", "del", world_if, check=False)  # a pair never moved: gone too

    atexit.register(remove)
    try:
        done = _ip("netns", "add", world_ns, check=False)
        if done.returncode != 0:
            said = done.stderr.strip()
            if "not permitted" in said.lower() or "permission denied" in said.lower():
                raise Unavailable(
                    f"network namespaces are not permitted here: `ip netns add` said {said!r}"
                )
            raise RuntimeError(f"ip netns add {world_ns}: {said}")
        made.append(world_ns)
        _ip("netns", "add", planner_ns)
        made.append(planner_ns)
        _ip("link", "add", world_if, "type", "veth", "peer", "name", planner_if)
        _ip("link", "set", world_if, "netns", world_ns)
        _ip("link", "set", planner_if, "netns", planner_ns)
        for ns, dev, host in ((world_ns, world_if, 1), (planner_ns, planner_if, 2)):
            _ip("-n", ns, "addr", "add", f"{subnet}.{host}/24", "dev", dev)
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "link", "set", dev, "up")
        yield Hosts(world_ns, planner_ns, world_if, planner_if, f"{subnet}.1", f"{subnet}.2")
    finally:
        remove()
        atexit.unregister(remove)


def namespaces() -> str:
    """``ip netns list`` (to check that none is left)."""
    return _ip("netns", "list", check=False).stdout
