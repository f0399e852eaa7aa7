"""Screenshots of the browser view (docs/media/view_*.png): runs ``m3p2i run SCENARIO --view``,
waits until the episode has run ``--at`` simulated seconds, and photographs the live page in
headless chromium (WebGL on the CPU); then the same episode's replay page at its end.

    python scripts/view_screenshots.py pick_place --at 1.8
    python scripts/view_screenshots.py push_pull_corner2 --at 3.0
    python scripts/view_screenshots.py navigation_seen --at 2.0
    python scripts/view_screenshots.py pick_place_seen --at 2.0

Needs m3p2i[view], chromium (apt-get install chromium) and a clone: the photographs are taken
by the tests' headless browser (tests/browser.py; no command of the product needs one). Prints
the files it wrote.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zmq

from m3p2i.launch import free_port_block
from m3p2i.view import ControlClient
from shared.endpoints import Endpoints
from shared.protocol import Control

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the clone's tests/ package
from tests.browser import chromium_screenshot


def _last_time(log: Path) -> float:
    """Simulated time of the newest step in an episode log being written (0 before any)."""
    if not log.is_file():
        return 0.0
    last = 0.0
    with log.open() as f:
        for line in f:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                break
            if rec.get("kind") == "step":
                last = rec["time"]
    return last


def _url(proc: subprocess.Popen, timeout: float = 180.0) -> str:
    end = time.monotonic() + timeout
    for line in proc.stdout:
        if line.startswith("view: "):
            return line.split(" ", 1)[1].strip()
        if time.monotonic() > end:
            break
    raise RuntimeError("the view printed no URL")


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scenario")
    ap.add_argument("--at", type=float, default=2.0, help="simulated seconds into the episode")
    ap.add_argument("--out", type=Path, default=Path("docs/media"), help="folder of the PNGs")
    ap.add_argument("--width", type=int, default=1000)
    ap.add_argument("--height", type=int, default=700)
    ap.add_argument(
        "--wait", type=float, default=6.0, help="wall seconds a page loads before its photograph"
    )
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    run_dir = Path(tempfile.mkdtemp(prefix="view-")) / "run"
    port = free_port_block()
    control = ControlClient(zmq.Context.instance(), Endpoints(port=port))
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "m3p2i",
            "run",
            args.scenario,
            "--view",
            "--run-dir",
            str(run_dir),
            "--port",
            str(port),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        url = _url(run)
        while _last_time(run_dir / "episode.jsonl") < args.at:
            if run.poll() is not None:
                raise RuntimeError(f"the episode ended before {args.at} s")
            time.sleep(0.2)
        # the world holds still while the page is photographed (a loaded machine takes a while)
        control.send(Control(op="pause"))
        live = args.out / f"view_{args.scenario}.png"
        chromium_screenshot(url, live, args.width, args.height, int(args.wait * 1000))
        print(f"wrote {live}")
        control.send(Control(op="resume"))
        run.wait()
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
            run.wait(30)
    replay = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "m3p2i",
            "view",
            "--log",
            str(run_dir),
            "--view-port",
            str(free_port_block(count=1)),
            "--duration",
            "120",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        url = _url(replay)
        out = args.out / f"view_{args.scenario}_replay.png"
        chromium_screenshot(url, out, args.width, args.height, int(args.wait * 1000))
        print(f"wrote {out}")
    finally:
        replay.send_signal(signal.SIGINT)
        replay.wait(30)


if __name__ == "__main__":
    main()
