"""Reading episode logs back: the JSON-lines files the world server writes
(``server/episode_log.py``). Record kinds (``kind`` field): ``header``, ``step``, ``event``,
``summary``. Used by the server's own summary, ``m3p2i bench``, ``m3p2i plot`` and ``record``.
"""

from __future__ import annotations

import json
from pathlib import Path

from shared.config import ConfigError
from shared.scenario import Scenario, load_scenario


def read_log(path: str | Path) -> list[dict]:
    """All complete records of a log (a torn last line from a crash is skipped)."""
    records = []
    with Path(path).open() as f:
        for line in f:
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                break
    return records


def episode_log_path(template: str | Path, seed: int) -> Path:
    """The log of ``seed``'s episode: ``{seed}`` (or e.g. ``{seed:03d}``) in ``template``
    replaced, so that a world serving several episodes (``--keep-serving``) writes each to its
    own file; a template without it is the path itself."""
    template = str(template)
    return Path(template.format(seed=seed) if "{seed" in template else template)


def has_summary(path: str | Path) -> bool:
    """Whether the log's last complete line is its ``summary`` (the episode is over and fully
    written); read from the end, so a waiting caller can ask often."""
    try:
        with Path(path).open("rb") as f:
            f.seek(0, 2)
            size = f.tell()
            block = min(size, 4096)
            while True:
                f.seek(size - block)
                tail = f.read(block)
                if not tail.endswith(b"\n"):
                    return False  # a line still being written
                lines = tail[:-1].rsplit(b"\n", 1)
                if len(lines) == 2 or block == size:
                    break
                block = min(size, block * 4)
    except OSError:
        return False
    try:
        return json.loads(lines[-1]).get("kind") == "summary"
    except (json.JSONDecodeError, AttributeError):
        return False


def header(records: list[dict]) -> dict:
    """The ``header`` record (the first one); an empty dict for a log cut before it."""
    return records[0] if records and records[0].get("kind") == "header" else {}


def faults(records: list[dict]) -> dict:
    """The simulated faults a log's world showed, from its header: ``{"faults": config,
    "faults_mismatch": factors, "faults_delays": ...}`` (server/faults.py), also from a log
    written before they were named so (``hardware``, ``hardware_mismatch``, ...); empty for
    none."""
    head, out = header(records), {}
    for part in ("", "_mismatch", "_delays"):
        for name in ("faults", "hardware"):
            if name + part in head:
                out["faults" + part] = head[name + part]
                break
    return out


def steps(records: list[dict]) -> list[dict]:
    """The ``step`` records, in order (state after each world step)."""
    return [r for r in records if r.get("kind") == "step"]


def summary(records: list[dict]) -> dict | None:
    """The ``summary`` record, or None when the world never wrote one (killed, crashed)."""
    return next((r for r in reversed(records) if r.get("kind") == "summary"), None)


def find_log(path: str | Path) -> Path:
    """An episode log: the file itself, or a run folder holding ``episode.jsonl``."""
    p = Path(path)
    if p.is_dir():
        p = p / "episode.jsonl"
    if not p.is_file():
        raise FileNotFoundError(
            f"no episode log at {path} (a .jsonl file or a run folder holding episode.jsonl)"
        )
    return p


def log_scenario(records: list[dict], override: str | None = None) -> Scenario:
    """The scenario a log was written for: the file named in its header, refused when its
    content changed since (replaying states into another model would show the wrong world);
    or ``override`` (a name or path), taken as given."""
    if override is not None:
        return load_scenario(override)
    head = header(records)
    if not head.get("source"):
        raise ConfigError(
            "episode log",
            "header.source",
            "the log names no scenario file",
            expected="--scenario NAME",
        )
    scenario = load_scenario(head["source"])
    if head.get("scenario_hash") not in (None, scenario.hash):
        raise ConfigError(
            scenario.source,
            "",
            "the scenario changed since the log was written",
            f"hash {scenario.hash}",
            f"hash {head['scenario_hash']} (pass --scenario "
            "with the version the log was written for)",
        )
    return scenario
