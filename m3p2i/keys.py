"""``m3p2i keys DIR``: a world's and a planner's CURVE key pairs, written in the key folder
layout :mod:`shared.security` describes (each side's sub-folder is all that side needs: the world
reads its own with ``server/keys.py``, the planner with ``planner_client/keys.py``)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import zmq.auth

from shared.config import ConfigError
from shared.security import ALLOW_PLANNER, ALLOW_WORLD, PLANNER, WORLD, require_curve


def make_keys(folder: Path) -> list[Path]:
    """Write a world and a planner key pair into ``folder`` in that layout (secret keys
    0600, the key folders 0700), the planner's public key already allowed by the world and the
    world's public key already beside the planner's pair. Refuses to replace existing keys
    (planners deployed with them would be locked out). Returns the files written."""
    require_curve()
    folder = Path(folder)
    world, planner = folder / WORLD, folder / PLANNER
    for existing in (world / "world.key_secret", planner / "planner.key_secret"):
        if existing.exists():
            raise ConfigError(
                str(existing),
                "",
                "keys already exist here; choose another "
                "folder, or delete this one first to replace them (every side "
                "that holds the old keys must then get the new ones)",
            )
    written = []
    old_umask = os.umask(0o077)  # the secret files never exist with looser modes, not even briefly
    try:
        for side in (world, planner):
            side.mkdir(parents=True, exist_ok=True)
            os.chmod(side, 0o700)
            zmq.auth.create_certificates(str(side), side.name)
        for allow in (world / ALLOW_WORLD, planner / ALLOW_PLANNER):
            allow.mkdir(exist_ok=True)
    finally:
        os.umask(old_umask)
    for public, copy in (
        (planner / "planner.key", world / ALLOW_WORLD / "planner.key"),
        (world / "world.key", planner / "world.key"),
    ):
        shutil.copyfile(public, copy)
    for side in (world, planner):
        for path in sorted(side.rglob("*")):
            if path.is_dir():
                os.chmod(path, 0o755)  # public-key folders: readable, like the public keys
            elif path.name.endswith(".key_secret"):
                os.chmod(path, 0o600)
            else:
                os.chmod(path, 0o644)
            written.append(path)
    return [p for p in written if p.is_file()]
