"""A real headless browser for the view's tests: Debian's ``chromium``, WebGL drawn by
SwiftShader (on the CPU), no network but loopback, a fresh profile each time."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from shared.tools.view import chromium_screenshot, find_chromium


def chromium() -> str:
    """The chromium executable. Missing: a failure in CI (``.ci/run`` installs it, so its
    absence is a broken set-up), a skip that says how to install it elsewhere."""
    exe = find_chromium()
    if exe:
        return exe
    if os.environ.get("CI"):
        pytest.fail("chromium is not installed: .ci/run must apt-get install chromium")
    pytest.skip("needs a headless browser: apt-get install chromium (CI installs it)")


def screenshot(url: str, out: Path, width: int = 1000, height: int = 700,
               wait_ms: int = 3000, check=None) -> np.ndarray:
    """Load ``url`` and return the page as an RGB array ``[height, width, 3]`` (also written
    to ``out``). With ``check`` (an image -> None that raises AssertionError), the page is
    photographed again each second until the check passes or two minutes end: a loaded
    machine draws the scene late, and the caller checks the last image."""
    from PIL import Image
    chromium()

    def as_image(png: bytes) -> np.ndarray:
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def ready(png: bytes) -> bool:
        try:
            check(as_image(png))
        except AssertionError:
            return False
        return True

    run = chromium_screenshot(url, out, width, height, wait_ms, ready=ready if check else None)
    assert out.is_file(), f"chromium wrote no screenshot (exit {run.returncode}):\n{run.stderr[-3000:]}"
    return as_image(out.read_bytes())


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
