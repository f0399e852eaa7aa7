"""``m3p2i run navigation_seen --view``, world, planner and view as processes: the page's scene
gets the lidar's points and the planner's field as its map makes them (the planner sends fields
to the view alone), the view records both, and the replay page of that run draws them again.
Read at the scene-graph level: the node names in what the page's websocket sends."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from m3p2i.launch import free_port_block
from tests.cli.test_view_keep import _lines, _page_frames, _wait_line
from tests.helpers import ENV, stop

pytestmark = pytest.mark.slow
pytest.importorskip("viser")

LAYERS = (b"/perception/scans/lidar", b"/perception/field")


def _scene_nodes(url: str, seconds: float = 120.0) -> set[bytes]:
    """Which of :data:`LAYERS` the page's websocket sends within ``seconds`` (or until the
    page goes)."""
    got, seen = b"", set()
    for frame in _page_frames(url, seconds):
        got = got[-4096:] + frame  # a node's name may straddle two messages
        seen |= {name for name in LAYERS if name in got}
        if len(seen) == len(LAYERS):
            break
    return seen


def _m3p2i(*args: str) -> subprocess.Popen:
    """``python -m m3p2i ARGS``, its output read line by line (:func:`_lines`)."""
    return subprocess.Popen(
        [sys.executable, "-m", "m3p2i", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
        stdin=subprocess.DEVNULL,
    )


def test_the_page_draws_the_lidars_points_and_the_planners_field_live_and_replayed(tmp_path):
    run_dir = tmp_path / "run"
    run = _m3p2i("run", "navigation_seen", "--view", "--run-dir", str(run_dir), "--timeout", "300")
    seen: list[str] = []
    try:
        url = _wait_line(_lines(run), "view: ", run, seen, 180).split(" ", 1)[1].strip()
        assert _scene_nodes(url) == set(LAYERS)
        run.wait(300)
    finally:
        stop(run)
    kinds = [json.loads(line).get("kind") for line in (run_dir / "diagnostics.jsonl").open()]
    assert kinds.count("scan") >= 2 and kinds.count("field") >= 1
    port = str(free_port_block(count=1))
    replay = _m3p2i("view", "--log", str(run_dir), "--view-port", port, "--duration", "300")
    try:
        url = _wait_line(_lines(replay), "view: ", replay, [], 180).split(" ", 1)[1].strip()
        assert _scene_nodes(url, 60.0) == set(LAYERS)
    finally:
        stop(replay)
