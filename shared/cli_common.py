"""Small helpers shared by the three command-line programs."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from rich.logging import RichHandler


def setup_logging(verbose: bool, name: str) -> None:
    """Rich output on a terminal; plain one-line records when redirected (log files, CI),
    where rich would wrap long lines at 80 columns."""
    level = logging.DEBUG if verbose else logging.INFO
    if sys.stderr.isatty():
        logging.basicConfig(level=level, format="%(message)s", datefmt="[%X]",
                            handlers=[RichHandler(show_path=False, markup=False)])
    else:
        logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger(name).setLevel(level)


def default_run_dir(scenario: str) -> Path:
    """``runs/<scenario>-<YYYYmmdd-HHMMSS>`` under the current directory."""
    return Path("runs") / f"{scenario}-{time.strftime('%Y%m%d-%H%M%S')}"


def summary_line(status: str, sim_time: float, measures: dict[str, float]) -> str:
    """One line for the end of an episode: outcome, simulated time, measures, planner Hz."""
    parts = [f"{status}", f"time {sim_time:.2f} s"]
    for k, v in measures.items():
        if k == "planner_hz":
            continue
        unit = " m" if k.startswith("distance") else ""
        parts.append(f"final {k} {v:.3f}{unit}")
    if "planner_hz" in measures:
        parts.append(f"planner {measures['planner_hz']:.1f} Hz")
    return ", ".join(parts)


ERROR_PREFIX = "error: "


def print_errors(errors, err: bool = True) -> None:
    """Each error on its own ``error: ...`` line(s), as ``m3p2i`` reads them back from the
    processes' ``--check``."""
    for e in errors:
        print(f"{ERROR_PREFIX}{e}", file=sys.stderr if err else sys.stdout)


def error_blocks(text: str) -> list[str]:
    """The messages :func:`print_errors` wrote into ``text`` (a message may span lines)."""
    blocks: list[str] = []
    for line in text.splitlines():
        if line.startswith(ERROR_PREFIX):
            blocks.append(line[len(ERROR_PREFIX):])
        elif blocks and line:
            blocks[-1] += "\n" + line
    return blocks
