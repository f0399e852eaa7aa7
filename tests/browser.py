"""A real headless browser for the view's tests: Debian's ``chromium``, WebGL drawn by
SwiftShader (on the CPU), no network but loopback, a fresh profile each time."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest


def chromium() -> str:
    """The chromium executable. Missing: a failure in CI (``.ci/run`` installs it, so its
    absence is a broken set-up), a skip that says how to install it elsewhere."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe:
        return exe
    if os.environ.get("CI"):
        pytest.fail("chromium is not installed: .ci/run must apt-get install chromium")
    pytest.skip("needs a headless browser: apt-get install chromium (CI installs it)")


def screenshot(url: str, out: Path, width: int = 1000, height: int = 700,
               wait_ms: int = 6000, timeout: float = 120.0) -> np.ndarray:
    """Load ``url`` and return the page as an RGB array ``[height, width, 3]`` (also written
    to ``out``). ``wait_ms`` of the page's own time lets the websocket deliver the scene."""
    from PIL import Image
    with tempfile.TemporaryDirectory() as profile:
        cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={profile}",
               # WebGL on the CPU: without SwiftShader headless chromium has no WebGL at all
               "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
               # nothing but loopback resolves: the page must load without the internet
               "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
               f"--window-size={width},{height}", f"--virtual-time-budget={wait_ms}",
               f"--screenshot={out}", url]
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert out.is_file(), f"chromium wrote no screenshot (exit {run.returncode}):\n{run.stderr[-3000:]}"
    return np.asarray(Image.open(out).convert("RGB"))


def colour_share(image: np.ndarray, rgb, tol: float = 40.0) -> float:
    """Share of the pixels within ``tol`` (Euclidean, 0-255) of colour ``rgb``."""
    d = np.linalg.norm(image.astype(float) - np.asarray(rgb, float), axis=-1)
    return float(np.mean(d < tol))


def hue_share(image: np.ndarray, channel: int, margin: int = 60) -> float:
    """Share of the pixels where ``channel`` (0 red, 1 green, 2 blue) exceeds both others by
    ``margin``: a lit red or green cube, whatever its shading."""
    img = image.astype(int)
    others = [c for c in range(3) if c != channel]
    return float(np.mean((img[..., channel] - img[..., others[0]] > margin)
                         & (img[..., channel] - img[..., others[1]] > margin)))
