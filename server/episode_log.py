"""Episode log: one JSON object per line, flushed as it is written.

Line-buffered JSONL survives Ctrl-C, a planner crash or a server crash: everything up to the last
complete line is on disk. Record kinds (``kind`` field): ``header``, ``step``, ``event``,
``summary``. The server's own metrics, ``m3p2i bench``, ``plot`` and ``record``, and the tests
read it back with :func:`read_log` (:mod:`server.evaluation.log_reader`, so that ``shared`` never
imports the server; re-exported here).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from server.evaluation.log_reader import read_log

__all__ = ["EpisodeLog", "read_log"]


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"cannot log {type(value).__name__}")


class EpisodeLog:
    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = self.path.open("w", buffering=1)  # line-buffered: each record hits the OS
        self._closed = False

    def write(self, kind: str, **fields: Any) -> None:
        if self._closed:
            return
        record = {"kind": kind, "wall": time.time(), **fields}
        self._f.write(json.dumps(record, default=_plain) + "\n")

    def event(self, what: str, **fields: Any) -> None:
        self.write("event", what=what, **fields)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._f.close()
