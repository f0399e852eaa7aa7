"""ZeroMQ CURVE security for both processes: key folders, socket set-up, the authenticator.

Beyond loopback the protocol must not let just anyone drive the robot, so every socket can use
libzmq's CURVE (Curve25519 key exchange, authenticated encryption; any ZeroMQ binding has it).
Which side is which:

- the **world** is the CURVE server on its control, state and command sockets; it accepts only
  clients whose public key is in its allow-list folder (checked by ZAP, in a thread);
- the **planner** is a CURVE client of the world (it knows the world's public key, so it cannot
  be talked into obeying an impostor) and the CURVE server of its diagnostics socket, which
  accepts its own key and those in its viewers folder;
- a **tool** (recorder, state watcher) is a client of either with the planner's key pair.

The key folder ``m3p2i keys DIR`` writes (each side's sub-folder is all that side needs)::

    DIR/world/world.key             the world's public key
    DIR/world/world.key_secret      the world's secret key (mode 0600, never leaves its machine)
    DIR/world/planners/*.key        allow list: public keys of the planners the world accepts
    DIR/planner/planner.key         the planner's public key
    DIR/planner/planner.key_secret  the planner's secret key (mode 0600)
    DIR/planner/world.key           the world's public key, which the planner checks
    DIR/planner/viewers/*.key       public keys of other diagnostics subscribers (optional)

The files are pyzmq's certificate format (``zmq.auth``): text with the Z85-encoded 32-byte key.
Each side loads its own sub-folder with the readers here: the world in ``server/keys.py``, the
planner and the tools beside it (and their CURVE client sockets) in ``planner_client/keys.py``.
"""

from __future__ import annotations

import ipaddress
import logging
import stat
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils.monitor import recv_monitor_message

from shared.config import ConfigError

log = logging.getLogger("m3p2i.security")

WORLD, PLANNER = "world", "planner"
ALLOW_WORLD = "planners"  # under DIR/world: the planners the world accepts
ALLOW_PLANNER = "viewers"  # under DIR/planner: other subscribers of the diagnostics

HOW_TO_MAKE_KEYS = (
    "make keys with `m3p2i keys DIR`, copy DIR/planner to the planner's machine (DIR/world "
    "stays on the world's), and start both sides with `--keys DIR`"
)


@dataclass(frozen=True)
class KeyPair:
    """A CURVE key pair, both keys Z85-encoded (40 bytes each); ``source`` names its file."""

    public: bytes
    secret: bytes
    source: str


# ------------------------------------------------------------------------------ key files


def side_folder(folder: Path, name: str) -> Path:
    """The ``name`` side's key folder: ``folder/name``, or ``folder`` itself if it is that."""
    if (folder / name).is_dir():
        return folder / name
    if folder.name == name and folder.is_dir():
        return folder
    raise ConfigError(
        str(folder),
        "",
        f"no {name}/ key folder here",
        expected=f"the folder `m3p2i keys DIR` made (with {name}/ in it)",
    )


def require_curve() -> None:
    """A ConfigError unless this libzmq has CURVE security."""
    if not zmq.has("curve"):
        raise ConfigError(
            "libzmq",
            "",
            f"this libzmq ({zmq.zmq_version()}) was built without CURVE security",
            expected="a pyzmq wheel from PyPI (it bundles a libzmq with CURVE)",
        )


def load_pair(secret_file: Path) -> KeyPair:
    """The key pair in ``secret_file``; ConfigError if missing, malformed or readable by others."""
    if not secret_file.is_file():
        raise ConfigError(
            str(secret_file),
            "",
            "secret key file missing",
            expected=f"the file `m3p2i keys DIR` writes; {HOW_TO_MAKE_KEYS}",
        )
    mode = stat.S_IMODE(secret_file.stat().st_mode)
    if mode & 0o077:
        raise ConfigError(
            str(secret_file),
            "",
            f"secret key readable by others (mode "
            f"{mode:04o}); refusing to use it: anyone who read it can impersonate "
            f"this side. Fix: chmod 600 {secret_file}",
        )
    try:
        public, secret = zmq.auth.load_certificate(str(secret_file))
    except (ValueError, OSError) as exc:
        raise ConfigError(str(secret_file), "", f"not a CURVE certificate: {exc}") from None
    if secret is None:
        raise ConfigError(str(secret_file), "", "has no secret-key line")
    _check_z85(public, secret_file)
    _check_z85(secret, secret_file)
    return KeyPair(public, secret, str(secret_file))


def load_public(path: Path) -> bytes:
    """The public key in ``path``; a missing or malformed file is a ConfigError."""
    if not path.is_file():
        raise ConfigError(
            str(path),
            "",
            "public key file missing",
            expected=f"the file `m3p2i keys DIR` writes; {HOW_TO_MAKE_KEYS}",
        )
    try:
        public, _ = zmq.auth.load_certificate(str(path))
    except (ValueError, OSError) as exc:
        raise ConfigError(str(path), "", f"not a CURVE certificate: {exc}") from None
    _check_z85(public, path)
    return public


def load_publics(folder: Path) -> set[bytes]:
    """The public keys of every ``*.key`` file in ``folder`` (none if it does not exist)."""
    if not folder.is_dir():
        return set()
    return {load_public(p) for p in sorted(folder.glob("*.key"))}


def _check_z85(key: bytes, path: Path) -> None:
    try:
        ok = len(key) == 40 and len(zmq.utils.z85.decode(key)) == 32
    except (ValueError, KeyError):
        ok = False
    if not ok:
        raise ConfigError(
            str(path),
            "",
            "malformed key",
            value=key.decode("ascii", "replace"),
            expected="40 characters of Z85 (a 32-byte Curve25519 key)",
        )


# ------------------------------------------------------------------------------ exposure


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a bind or connect address) is loopback only. Anything else (an IP of
    an interface, ``0.0.0.0``, ``*``, an interface or host name) counts as a network."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def exposure_error(hosts: dict[str, str], keys: Path | None, insecure: bool) -> str | None:
    """Why these addresses (option -> host) may not be used as given: a network address
    without keys, unless ``insecure``; keys and ``insecure`` together. None when fine."""
    if keys is not None and insecure:
        return "--keys and --insecure contradict each other: give one"
    exposed = [f"{opt} {host}" for opt, host in hosts.items() if not is_loopback(host)]
    if exposed and keys is None and not insecure:
        return (
            f"{', '.join(exposed)} is a network address, and without keys the protocol is "
            f"neither authenticated nor encrypted: anyone who reaches the ports could drive "
            f"the robot or read its state. To secure it, {HOW_TO_MAKE_KEYS}. To run "
            f"unprotected anyway (an isolated, trusted network only), add --insecure"
        )
    return None


def insecure_warning(hosts: dict[str, str]) -> str | None:
    """The warning for ``--insecure`` on a network address (None on loopback)."""
    exposed = [f"{opt} {host}" for opt, host in hosts.items() if not is_loopback(host)]
    if not exposed:
        return None
    return (
        f"INSECURE: {', '.join(exposed)} without CURVE keys (--insecure): the traffic is "
        f"neither authenticated nor encrypted; anyone on the network can drive the robot"
    )


class ExposureError(ValueError):
    """A network address without keys (and without --insecure), or contradictory options."""


def keys_for_cli(hosts: dict[str, str], keys: Path | None, insecure: bool, load, warn):
    """What a command-line program does before it opens anything: refuse a network address
    without keys (ExposureError, unless ``insecure``: then ``warn`` is called with the
    warning, at every start), and load the keys with ``load`` (ConfigError on a bad file).
    Returns the loaded keys, or None without ``keys``."""
    problem = exposure_error(hosts, keys, insecure)
    if problem:
        raise ExposureError(problem)
    if insecure and (warning := insecure_warning(hosts)):
        warn(warning)
    return None if keys is None else load(keys)


# ------------------------------------------------------------------------------ sockets


def curve_server(sock: zmq.Socket, own: KeyPair) -> None:
    """Make ``sock`` (before bind/connect) the CURVE server with ``own`` keys."""
    sock.curve_server = True
    sock.curve_publickey = own.public
    sock.curve_secretkey = own.secret


@dataclass(frozen=True)
class Refusal:
    """A peer the authenticator refused: its address and Z85 public key."""

    address: str
    key: str


class Authenticator:
    """ZAP for every CURVE-server socket of one context (pyzmq's ThreadAuthenticator): accepts
    the client keys in ``allowed``; each refusal is logged (with the peer's address and key)
    and queued for :meth:`refusals`, so the owner can write it to its own log from its thread.
    The queue keeps the newest :attr:`MAX_QUEUED` (an owner that never reads it, as the planner,
    must not grow it while a peer with a wrong key retries); :attr:`dropped` counts the rest."""

    MAX_QUEUED = 256

    def __init__(self, ctx: zmq.Context, allowed: frozenset[bytes], what: str):
        self.allowed = allowed
        self.what = what
        self._refused: deque[Refusal] = deque(maxlen=self.MAX_QUEUED)  # appends: thread-safe
        self._count = 0
        self.dropped = 0
        self._auth = _AddressAuthenticator(ctx, log=logging.getLogger("m3p2i.security.zap"))
        self._auth.start()
        self._auth.configure_curve_callback("*", credentials_provider=self)

    def callback(self, domain: str, key: bytes) -> bool:  # called by the ZAP thread
        if key in self.allowed:
            return True
        self._count += 1
        refusal = Refusal(self._auth.peer, key.decode("ascii", "replace"))
        if self._count <= 10 or self._count % 100 == 0:
            log.warning(
                "%s refused a peer at %s: public key %s is not in the allow list "
                "(%d refusals so far)",
                self.what,
                refusal.address,
                refusal.key,
                self._count,
            )
        if len(self._refused) == self.MAX_QUEUED:
            self.dropped += 1
        self._refused.append(refusal)
        return False

    def refusals(self) -> list[Refusal]:
        """The refusals since the last call, the newest :attr:`MAX_QUEUED` (thread-safe)."""
        out = []
        while True:
            try:
                out.append(self._refused.popleft())
            except IndexError:
                return out

    def stop(self) -> None:
        self._auth.stop()


class _AddressAuthenticator(ThreadAuthenticator):
    """Keeps the address of the request being handled, which the key callback does not get
    (ZAP requests are handled one at a time, in the authenticator's thread)."""

    peer = "?"

    async def handle_zap_message(self, msg: list[bytes]) -> None:
        if len(msg) > 3:
            self.peer = msg[3].decode("utf-8", "replace")
        await super().handle_zap_message(msg)


_PROTOCOL_ERRORS = {
    0x11000001: "a CURVE message failed to decrypt (the peer has another public key for this side)",
    0x11000002: "security mechanism mismatch (one side uses CURVE keys, the other none)",
}


def describe_handshake_failure(event: int, value: int) -> str:
    """A reader's description of a ZMQ_EVENT_HANDSHAKE_FAILED_* monitor event."""
    if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
        return f"the peer refused our key (ZAP status {value})"
    if event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        return _PROTOCOL_ERRORS.get(value, f"protocol error 0x{value:x} in the handshake")
    if event == zmq.EVENT_DISCONNECTED:
        return (
            "the peer closed the connection before the handshake succeeded (keys that do "
            "not match, or one side without keys)"
        )
    return (
        "the handshake failed without detail (keys that do not match: another public key "
        "for the server, or none)"
    )


HANDSHAKE_FAILURES = (
    zmq.EVENT_HANDSHAKE_FAILED_AUTH
    | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
)


class HandshakeMonitor:
    """Watches a socket for failed ZMTP handshakes (ZeroMQ's socket monitor): the only way a
    side learns that CURVE refused a connection, which otherwise just never delivers.

    With ``hangups``, a connection that the peer closes before any handshake succeeded counts
    as a failure too (``EVENT_DISCONNECTED``): a CURVE world hanging up on a keyless client does
    not always say why (seen: one start in five of three planners at once got no
    ``HANDSHAKE_FAILED`` event at all). A world that is still starting refuses connections
    instead, and one that is up completes the handshake in ZeroMQ's own thread."""

    def __init__(self, sock: zmq.Socket, hangups: bool = False):
        self.sock = sock
        self.hangups = hangups
        extra = (
            zmq.EVENT_CONNECTED | zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_DISCONNECTED
            if hangups
            else 0
        )
        self.mon = sock.get_monitor_socket(HANDSHAKE_FAILURES | extra)
        self._connected = False  # a connection whose handshake has not succeeded yet
        self.stalled = False  # (hangups) the last connection neither succeeded nor failed yet
        self.events = 0  # monitor events seen: 0, no connection got as far as the peer

    def failures(self) -> list[tuple[int, int]]:
        """``(event, value)`` of the failures since the last call."""
        out = []
        while self.mon.poll(0):
            msg = recv_monitor_message(self.mon)
            event, value = int(msg["event"]), int(msg["value"])
            self.events += 1
            if event == zmq.EVENT_CONNECTED:
                self._connected = True
            elif event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self._connected = False
            elif event == zmq.EVENT_DISCONNECTED:
                if self._connected:
                    out.append((event, value))
                self._connected = False
            else:
                self._connected = False  # reported as a failure of its own
                out.append((event, value))
        self.stalled = self._connected
        return out

    def close(self) -> None:
        try:
            self.sock.disable_monitor()
        except zmq.ZMQError:
            pass  # the socket is already closed
        self.mon.close(0)
