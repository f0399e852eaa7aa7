"""MuJoCo's viewer on the world server (``m3p2i-server --window``) opens framing the scene: run
under a virtual display (Xvfb), its window must show the Panda's table with both cubes, not the
table's edge (MuJoCo's default camera frames the whole model, floor included)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from m3p2i.launch import free_port_block
from server.cli import scene_framing
from shared.scenario import load_scenario
from shared.scene import compile_model, initial_data
from tests.browser import hue_share
from tests.helpers import ENV, stop


def _xvfb() -> str:
    exe = shutil.which("Xvfb")
    if exe:
        return exe
    if os.environ.get("CI"):
        pytest.fail("Xvfb is not installed: .ci/run must apt-get install xvfb")
    pytest.skip("needs a virtual display: apt-get install xvfb (CI installs it)")


def test_scene_framing_covers_the_table_and_leaves_the_floor_out():
    sc = load_scenario("pick_place")
    model = compile_model(sc)
    centre, radius = scene_framing(model, initial_data(sc, model))
    assert 0.6 < radius < 2.0  # the table (1.2 m) and the arm, no floor
    assert centre[2] > 0.9  # at the table's height
    sc = load_scenario("push_pull_corner2")
    model = compile_model(sc)
    centre, radius = scene_framing(model, initial_data(sc, model))
    assert radius == pytest.approx(np.hypot(8, 8) / 2, rel=0.05)  # the 8 m arena's walls


def test_the_viewer_opens_looking_at_the_robot_and_the_cubes(tmp_path):
    from PIL import ImageGrab

    xvfb = subprocess.Popen(
        [_xvfb(), "-displayfd", "1", "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        stdout=subprocess.PIPE,
        text=True,
    )
    server = None
    try:
        display = ":" + xvfb.stdout.readline().strip()
        env = {**ENV, "DISPLAY": display}
        env.pop("WAYLAND_DISPLAY", None)
        server = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "server",
                "--scenario",
                "pick_place",
                "--window",
                "--port",
                str(free_port_block()),
                "--log",
                str(tmp_path / "episode.jsonl"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        end = time.monotonic() + 60
        red = green = 0.0
        while time.monotonic() < end and server.poll() is None:
            time.sleep(0.5)
            image = np.asarray(ImageGrab.grab(xdisplay=display).convert("RGB"))
            red, green = hue_share(image, 0), hue_share(image, 1)
            if red > 5e-5 and green > 3e-5:
                break
        ImageGrab.grab(xdisplay=display).save(tmp_path / "viewer.png")
        assert server.poll() is None, f"the server exited:\n{server.communicate()[0]}"
        # both 5 cm cubes in view, each over a few dozen pixels of the 1024x768 screen
        assert red > 5e-5 and green > 3e-5, (
            f"cubes not in view (red {red:.5f}, green {green:.5f}); see {tmp_path / 'viewer.png'}"
        )
        assert image.std() > 20
    finally:
        if server is not None:
            stop(server)
        xvfb.terminate()
        xvfb.wait(10)
