"""Where scenario, objective and bench files are found: the user's folders first, then the files
shipped with m3p2i (docs/scenarios.md, "Where scenarios are looked up").

A name (``navigation``) is looked up as ``NAME.yaml``; anything that is a file is taken as given.
Scenario folders, in order: each folder of ``M3P2I_SCENARIOS`` (separated by ``os.pathsep``),
``configs/scenarios`` of the current folder, then the shipped scenarios. Objective, bench and
robot files are looked up in the ``objectives``, ``bench`` and ``robots`` folders beside each of
those user folders (a user's ``configs/`` is laid out like the shipped one), then in the shipped
ones (the shipped robots are ``shared/robots``). The first folder
that has the name wins, so a user's file shadows a shipped file of the same name.

The shipped files are the repository's top-level ``configs/``: a wheel carries it as the data
folder ``shared/configs`` (pyproject.toml maps it there), found with :mod:`importlib.resources`;
a clone, installed editable or not, reads ``configs/`` where it is.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from shared.config import ConfigError

ENV_VAR = "M3P2I_SCENARIOS"
KINDS = {
    "scenarios": "scenario",
    "objectives": "objectives",
    "bench": "bench",
    "robots": "robot",
}  # folder: what


def shipped_configs() -> Path:
    """The shipped ``configs/`` folder: inside the installed package, else the source tree's."""
    packaged = resources.files("shared") / "configs"
    # pip installs a wheel as plain files, so the resource is a filesystem path (which the two
    # processes and MuJoCo need); a clone has no shared/configs and uses configs/ itself
    if isinstance(packaged, Path) and packaged.is_dir():
        return packaged
    return Path(__file__).resolve().parent.parent / "configs"


def shipped(*parts: str) -> Path:
    """A path inside the shipped ``configs/``, e.g. ``shipped("scenarios")``; the shipped robot
    files live beside their MJCF in ``shared/robots``, so ``shipped("robots")`` is that folder."""
    if parts and parts[0] == "robots":
        return Path(__file__).resolve().parent.joinpath(*parts)
    return shipped_configs().joinpath(*parts)


@dataclass(frozen=True)
class Folder:
    """A folder searched for one kind of file, and why it is searched: ``M3P2I_SCENARIOS``,
    ``current folder`` or ``shipped``."""

    path: Path
    origin: str

    def __str__(self) -> str:
        if self.origin == "shipped":
            return f"shipped {self.path}"
        return f"{shown(self.path)} ({self.origin})"


def user_folders(kind: str = "scenarios") -> list[Folder]:
    """The user's folders for ``kind`` (a key of :data:`KINDS`), in lookup order; they need not
    exist."""
    env = [
        Folder(Path(p).expanduser().absolute(), ENV_VAR)
        for p in os.environ.get(ENV_VAR, "").split(os.pathsep)
        if p
    ]
    scenario_folders = [*env, Folder(Path.cwd() / "configs" / "scenarios", "current folder")]
    if kind == "scenarios":
        return scenario_folders
    return [Folder(f.path.parent / kind, f.origin) for f in scenario_folders]


def search_folders(kind: str = "scenarios") -> list[Folder]:
    """Every folder searched for ``kind``, in lookup order: the user's, then the shipped one.
    A folder named twice counts once; a user folder that is the shipped one (the current folder
    is the repository) counts as shipped."""
    last = Folder(shipped(kind), "shipped")
    seen = {last.path.resolve()}
    out = []
    for folder in user_folders(kind):
        key = folder.path.resolve()
        if key not in seen:
            seen.add(key)
            out.append(folder)
    return [*out, last]


def find(name_or_path: str | os.PathLike, kind: str = "scenarios") -> Path:
    """A file of ``kind``: the path as given, else ``NAME.yaml`` in the first folder of
    :func:`search_folders` that has it. The error lists every name found and the folders
    searched."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    folders = search_folders(kind)
    for folder in folders:
        candidate = folder.path / f"{p.name}.yaml"
        if candidate.is_file():
            return candidate
    known = ", ".join(sorted({e.name for e in entries(kind)}))
    raise ConfigError(
        str(name_or_path),
        "",
        f"no such {KINDS[kind]} file or name",
        expected=f"a YAML path or one of: {known}; looked in: {'; '.join(str(f) for f in folders)}",
    )


@dataclass(frozen=True)
class Entry:
    """A file of some kind in one of the searched folders. ``shadowed_by``: the file of the same
    name in an earlier folder, which is the one used; None when this one is used."""

    name: str
    path: Path
    folder: Folder
    shadowed_by: Path | None = None


def entries(kind: str = "scenarios") -> list[Entry]:
    """Every ``*.yaml`` in the searched folders, folder by folder in lookup order, sorted by name
    within a folder; shadowed files included (and marked)."""
    used: dict[str, Path] = {}
    out = []
    for folder in search_folders(kind):
        for path in sorted(folder.path.glob("*.yaml")):
            first = used.setdefault(path.stem, path)
            out.append(Entry(path.stem, path, folder, None if first == path else first))
    return out


def shown(path: Path) -> str:
    """``path`` as a user would type it: relative (``./configs/scenarios``) under the current
    folder, else absolute."""
    try:
        return f"./{Path(path).absolute().relative_to(Path.cwd())}"
    except ValueError:
        return str(path)
