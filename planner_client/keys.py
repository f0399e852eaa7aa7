"""The planner's CURVE keys (a tool beside the planner, such as ``m3p2i view`` or
``m3p2i record``, uses the same): its own pair, the world's public key it checks and the
subscribers its diagnostics socket accepts, loaded from its side of the key folder that
``m3p2i keys DIR`` writes (``DIR/planner/``); and a socket made a CURVE client of the world (or
of the planner's diagnostics). The folder's layout, the file format and the checks of each file
are the contract both sides share (:mod:`shared.security`); the world loads its own side in
``server/keys.py``. Light to import (zmq, no torch): ``m3p2i`` reads it too."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import zmq

from shared.security import (
    ALLOW_PLANNER,
    PLANNER,
    KeyPair,
    load_pair,
    load_public,
    load_publics,
    require_curve,
    side_folder,
)


@dataclass(frozen=True)
class PlannerKeys:
    """What the planner (and a tool beside it) needs: its own pair, the world's public key to
    check, and the subscribers its diagnostics socket accepts (its own key and the viewers')."""

    own: KeyPair
    world: bytes
    viewers: frozenset[bytes]


def load_planner_keys(folder: Path) -> PlannerKeys:
    """The planner's keys from ``folder`` (the DIR of ``m3p2i keys DIR``, or its ``planner``
    sub-folder); a missing or malformed file or a secret key readable by others is a
    ConfigError naming the file and the fix."""
    require_curve()
    side = side_folder(Path(folder), PLANNER)
    own = load_pair(side / "planner.key_secret")
    world = load_public(side / "world.key")
    viewers = load_publics(side / ALLOW_PLANNER) if (side / ALLOW_PLANNER).is_dir() else set()
    return PlannerKeys(own, world, frozenset(viewers | {own.public}))


def curve_client(sock: zmq.Socket, own: KeyPair, server_public: bytes) -> None:
    """Make ``sock`` (before connect) a CURVE client of the server with ``server_public``."""
    sock.curve_publickey = own.public
    sock.curve_secretkey = own.secret
    sock.curve_serverkey = server_public
