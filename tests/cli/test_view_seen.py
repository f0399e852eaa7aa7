"""``m3p2i run navigation_seen --view``, world, planner and view as processes: the page's scene
gets the lidar's points and the planner's field as its map makes them (the planner sends fields
to the view alone), the view records both, and the replay page of that run draws them again.
Read at the scene-graph level: the node names in what the page's websocket sends."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from m3p2i.launch import free_port_block
from tests.cli.test_view_keep import _inflate, _lines, _wait_line
from tests.helpers import ENV, stop

pytestmark = pytest.mark.slow
pytest.importorskip("viser")

LAYERS = (b"/perception/scans/lidar", b"/perception/field")


def _scene_nodes(url: str, seconds: float = 120.0) -> set[bytes]:
    """Which of :data:`LAYERS` the page's websocket sends within ``seconds`` (or until the
    page goes)."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    got, seen = b"", set()
    with connect(
        url.replace("http://", "ws://"),
        origin=url.rstrip("/"),
        open_timeout=10,
        max_size=None,
        subprotocols=["viser-v1.1.1", "viser"],
    ) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end and len(seen) < len(LAYERS):
            try:
                msg = ws.recv(timeout=max(0.1, end - time.monotonic()))
            except (TimeoutError, ConnectionClosed):  # the episode, and the page, ended
                break
            got = got[-4096:] + _inflate(msg if isinstance(msg, bytes) else msg.encode())
            seen |= {name for name in LAYERS if name in got}
    return seen


def test_the_page_draws_the_lidars_points_and_the_planners_field_live_and_replayed(tmp_path):
    run_dir = tmp_path / "run"
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "m3p2i",
            "run",
            "navigation_seen",
            "--view",
            "--run-dir",
            str(run_dir),
            "--timeout",
            "300",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
        stdin=subprocess.DEVNULL,
    )
    seen: list[str] = []
    try:
        url = _wait_line(_lines(run), "view: ", run, seen, 180).split(" ", 1)[1].strip()
        assert _scene_nodes(url) == set(LAYERS)
        run.wait(300)
    finally:
        stop(run)
    kinds = [json.loads(line).get("kind") for line in (run_dir / "diagnostics.jsonl").open()]
    assert kinds.count("scan") >= 2 and kinds.count("field") >= 1
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
            "300",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )
    try:
        url = _wait_line(_lines(replay), "view: ", replay, [], 180).split(" ", 1)[1].strip()
        assert _scene_nodes(url, 60.0) == set(LAYERS)
    finally:
        stop(replay)
