"""The world's CURVE keys: its own pair and the planners' public keys it accepts, loaded from
its side of the key folder that ``m3p2i keys DIR`` writes (``DIR/world/``). The folder's layout,
the file format and the checks of each file are the contract both sides share
(:mod:`shared.security`); the planner loads its own side in ``planner_client/keys.py``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from shared.config import ConfigError
from shared.security import (
    ALLOW_WORLD,
    WORLD,
    KeyPair,
    load_pair,
    load_publics,
    require_curve,
    side_folder,
)


@dataclass(frozen=True)
class WorldKeys:
    """What the world needs: its own pair and the planners' public keys it accepts."""

    own: KeyPair
    allowed: frozenset[bytes]
    allow_dir: Path


def load_world_keys(folder: Path) -> WorldKeys:
    """The world's keys from ``folder`` (the DIR of ``m3p2i keys DIR``, or its ``world``
    sub-folder); a missing or malformed file, a secret key readable by others or an empty
    allow list is a ConfigError naming the file and the fix."""
    require_curve()
    side = side_folder(Path(folder), WORLD)
    own = load_pair(side / "world.key_secret")
    allow_dir = side / ALLOW_WORLD
    allowed = load_publics(allow_dir)
    if not allowed:
        raise ConfigError(
            str(allow_dir),
            "",
            "no planner public key to accept (the world would refuse every planner)",
            expected="at least one *.key file, "
            "e.g. a copy of the planner's DIR/planner/planner.key",
        )
    return WorldKeys(own, frozenset(allowed), allow_dir)
