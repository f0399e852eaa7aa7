"""``m3p2i check``: every error of a scenario file, before any process starts.

Both processes check what they will use: the world its success test, disturbances and metrics;
the planner its cost terms, pinned controls, observers and MPPI parameters, against the
compiled model and its registries. Only they know those registries, and the tools never import
them (docs/layout in the README), so each runs once with ``--check`` (in parallel) and this
merges their messages (:func:`error_blocks` reads them back from the processes' output), each
message once, in the order they came.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from shared.cli_common import ERROR_PREFIX

CHECK_TIMEOUT = 300.0  # seconds; a check compiles the model once per process


def scenario_errors(path: str | Path, plugins: Sequence[str] = ()) -> list[str]:
    """The messages of every error the world and the planner find in the scenario at
    ``path`` (the planner with its ``--plugins``); empty when both accept it."""
    extra = {"server": [], "planner_client": [a for p in plugins for a in ("--plugins", p)]}
    procs = {
        name: subprocess.Popen(
            [sys.executable, "-m", name, "--scenario", str(path), "--check", *extra[name]],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("server", "planner_client")
    }
    messages: list[str] = []
    for name, proc in procs.items():
        try:
            out, err = proc.communicate(timeout=CHECK_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        blocks = error_blocks(out)
        if proc.returncode not in (0, 2) or (proc.returncode == 2 and not blocks):
            tail = "\n".join(err.strip().splitlines()[-5:])
            blocks.append(f"the {name} check failed (exit code {proc.returncode}): {tail}")
        messages += [b for b in blocks if b not in messages]
    return messages


def error_blocks(text: str) -> list[str]:
    """The messages :func:`shared.cli_common.print_errors` wrote into ``text`` (a message may
    span lines)."""
    blocks: list[str] = []
    for line in text.splitlines():
        if line.startswith(ERROR_PREFIX):
            blocks.append(line[len(ERROR_PREFIX) :])
        elif blocks and line:
            blocks[-1] += "\n" + line
    return blocks
