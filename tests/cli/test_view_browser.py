"""The browser view in a real headless browser (chromium, WebGL on the CPU, no network but
loopback): the live page while ``m3p2i run pick_place --view`` runs, then the replay page of
that episode's log. Each screenshot must show the scene: not blank, the Panda's white arm and
dark mount, the red and the green cube."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq

from m3p2i.launch import free_port_block
from m3p2i.view import ControlClient
from shared import protocol as P
from shared.endpoints import Endpoints
from tests.browser import chromium, hue_share, screenshot
from tests.helpers import ENV, _sigint_as_in_a_terminal, stop

pytestmark = pytest.mark.slow


def _start(args: list[str]) -> tuple[subprocess.Popen, str]:
    """Start ``m3p2i ARGS`` and return it with the URL it prints (``view: URL``)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "m3p2i", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
        preexec_fn=_sigint_as_in_a_terminal,
    )
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    end, seen = time.monotonic() + 180, []
    while time.monotonic() < end:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        if line.startswith("view: "):
            url = line.split(" ", 1)[1].strip()
            assert url.startswith("http://127.0.0.1:"), url  # loopback by default
            return proc, url
    stop(proc)
    raise AssertionError("no 'view: URL' line:\n" + "".join(seen))


def _scene(image: np.ndarray) -> np.ndarray:
    """The 3D part of a 1000×700 page: left of the panel, below the browser's notice about
    software WebGL, above the axes icon."""
    return image[160:640, :650]


def _check_pick_place(image: np.ndarray) -> None:
    assert image.std() > 20, "the page is blank"
    scene = _scene(image).astype(int)
    mx, mn = scene.max(-1), scene.min(-1)
    # the white arm (rgba 0.95) as lit and shaded grey, darker than the floor and the page
    arm = np.mean((mx < 215) & (mn > 120) & (mx - mn < 15))
    # the mount (0.3, 0.3, 0.32): dark slate
    mount = np.mean((mx < 140) & (mn > 40) & (scene[..., 2] - scene[..., 0] > 10))
    red, green = hue_share(scene, 0), hue_share(scene, 1)
    assert arm > 2e-3, f"no Panda arm drawn ({arm:.4f} of the scene)"
    assert mount > 1e-4, f"no Panda mount drawn ({mount:.5f})"
    assert red > 1e-4, f"no red cube ({red:.5f})"
    assert green > 5e-5, f"no green cube ({green:.5f})"


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """``m3p2i run pick_place --view``: a screenshot of the live page, then the run is
    interrupted (Ctrl-C) and its run folder, with a partial log, is handed on."""
    chromium()
    tmp = tmp_path_factory.mktemp("view")
    run_dir = tmp / "run"
    port = free_port_block()
    proc, url = _start(
        [
            "run",
            "pick_place",
            "--view",
            "--run-dir",
            str(run_dir),
            "--timeout",
            "600",
            "--port",
            str(port),
        ]
    )
    try:
        # paused, the lock-step world holds its state and the planner, having answered it,
        # stops planning: the browser gets the cores (2 here) to draw the page
        control = ControlClient(zmq.Context.instance(), Endpoints(port=port), timeout=30)
        ok, reply = control.send(P.Control(op="pause"))
        assert ok, reply
        image = screenshot(url, tmp / "live.png", check=_check_pick_place)
        # resumed, the world steps: the view records what the planner publishes and the log
        # gets the steps the replay shows
        ok, reply = control.send(P.Control(op="resume"))
        assert ok, reply
        end = time.monotonic() + 120
        diags, log = run_dir / "diagnostics.jsonl", run_dir / "episode.jsonl"
        while time.monotonic() < end and not (
            diags.is_file() and diags.stat().st_size > 0 and '"kind": "step"' in log.read_text()
        ):
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGINT)  # m3p2i run stops all its processes
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            stop(proc)
    return image, run_dir, tmp


def test_the_live_page_draws_the_scene_and_records_the_planners_trajectories(live):
    image, run_dir, _ = live
    _check_pick_place(image)
    # what the view received from the planner and keeps for the replay: each mode's best
    # trajectories, with their modes (a 12-step horizon at 0.01 s is too short to see at t=0)
    records = [json.loads(line) for line in (run_dir / "diagnostics.jsonl").open()]
    assert records and records[0]["mode_names"] == ["reach"]
    top = np.asarray(records[0]["top"])
    assert top.ndim == 3 and top.shape[2] == 3 and len(records[0]["top_modes"]) == len(top)


def test_the_replay_page_draws_the_logged_episode(live):
    _, run_dir, tmp = live
    assert (run_dir / "episode.jsonl").is_file()
    proc, url = _start(
        [
            "view",
            "--log",
            str(run_dir),
            "--view-port",
            str(free_port_block(count=1)),
            "--duration",
            "300",
        ]
    )
    try:
        image = screenshot(url, tmp / "replay.png", check=_check_pick_place)
    finally:
        stop(proc)
    _check_pick_place(image)
