"""``m3p2i new NAME --from SCENARIO``: a copy of a scenario (usually a shipped one) in the user's
scenario folder, to start one's own from. It never overwrites a file."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from shared.config import ConfigError
from shared.config_files import find, shown, user_folders

NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
# the top-level `name:` line; the value only, so that a comment after it stays a comment
NAME_LINE = re.compile(r"^name:[ \t]*[^\s#]+", re.MULTILINE)


@dataclass(frozen=True)
class NewScenario:
    path: Path  # the file written
    source: Path  # the file it copies


def new_scenario(name: str, source: str) -> NewScenario:
    """Copy scenario ``source`` (a name or path) to ``NAME.yaml`` in the first user scenario
    folder (the first of ``M3P2I_SCENARIOS``, else ``./configs/scenarios``), its ``name:`` set to
    NAME; the first line says where it came from. Raises :class:`ConfigError` for a bad name, an
    unknown source or an existing file."""
    if not NAME.fullmatch(name):
        raise ConfigError(
            name,
            "",
            "not a scenario name",
            expected="letters, digits, '_', '.' "
            "and '-', without a path (the file becomes NAME.yaml)",
        )
    src = find(source, "scenarios")
    text, count = NAME_LINE.subn(f"name: {name}", src.read_text(), count=1)
    if count != 1 or (yaml.safe_load(text) or {}).get("name") != name:
        raise ConfigError(
            str(src),
            "name",
            "no top-level `name: ...` line to set to the new name",
            expected="a scenario file with a `name:` line",
        )
    folder = user_folders("scenarios")[0].path
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f"{name}.yaml"
    try:
        with target.open("x") as f:  # "x": fails if the file exists, atomically
            f.write(f"# Started from {shown(src)} by `m3p2i new`.\n{text}")
    except FileExistsError:
        raise ConfigError(
            shown(target),
            "",
            "exists already (m3p2i new never overwrites)",
            expected="another NAME, or remove the file first",
        ) from None
    return NewScenario(target, src)
