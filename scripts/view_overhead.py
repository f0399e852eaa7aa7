"""What the browser view costs the planner: the same lock-step episode run with and without
``--view``, interleaved (so background load hits both alike), and the planner's rate of each
(the episode summary's ``planner_hz``: mean over its planning iterations).

    python scripts/view_overhead.py                       # pick_place, 3 pairs
    python scripts/view_overhead.py -s push_pull -n 5

Lock-step episodes take the same steps with or without a view (the view only subscribes), so
the rates compare like for like. No browser is attached here: a browser runs on the user's
machine, not beside the planner. Prints one line per run and the median and range of each.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from measure.options import positive_int


def run_once(scenario: str, view: bool, folder: Path) -> tuple[float, int, float]:
    """(planner Hz, steps, wall seconds) of one ``m3p2i run``."""
    run_dir = folder / f"{scenario}-{'view' if view else 'plain'}-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "m3p2i", "run", scenario, "--run-dir", str(run_dir)]
    if view:
        cmd.append("--view")
    started = time.monotonic()
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    wall = time.monotonic() - started
    if run.returncode not in (0, 1):  # 1: the episode ended unsuccessfully, its log is kept
        tail = "\n".join((run.stdout + run.stderr).strip().splitlines()[-6:])
        sys.exit(f"error: {' '.join(cmd[2:])} exited with code {run.returncode}:\n{tail}")
    summary = next(
        json.loads(line)
        for line in reversed((run_dir / "episode.jsonl").read_text().splitlines())
        if json.loads(line).get("kind") == "summary"
    )
    return float(summary["planner_hz"]), int(summary["steps"]), wall


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("-s", "--scenario", default="pick_place")
    ap.add_argument("-n", "--pairs", type=positive_int, default=3, help="runs with and without")
    args = ap.parse_args()
    rates: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.pairs):
            for view in (False, True) if i % 2 == 0 else (True, False):
                hz, steps, wall = run_once(args.scenario, view, Path(tmp))
                rates[view].append(hz)
                print(
                    f"{args.scenario} {'view ' if view else 'plain'} planner {hz:6.2f} Hz, "
                    f"{steps} steps, {wall:5.1f} s wall",
                    flush=True,
                )
    for view in (False, True):
        r = rates[view]
        print(
            f"{'with view   ' if view else 'without view'}: median {statistics.median(r):.2f} Hz "
            f"(range {min(r):.2f}-{max(r):.2f}, {len(r)} runs)"
        )


if __name__ == "__main__":
    main()
