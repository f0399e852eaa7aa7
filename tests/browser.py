"""A real headless browser for the view's tests: Debian's ``chromium``, WebGL drawn by
SwiftShader (on the CPU), no network but loopback, a fresh profile each time."""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest


def find_chromium() -> str | None:
    """Debian's ``chromium`` (or ``chromium-browser``) on the PATH, or None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def chromium_screenshot(
    url: str,
    out: Path,
    width: int = 1000,
    height: int = 700,
    wait_ms: int = 6000,
    timeout: float = 120.0,
    ready=None,
) -> subprocess.CompletedProcess:
    """Load ``url`` in headless chromium and write a PNG of the page to ``out``, ``wait_ms``
    of wall-clock time after asking for it (the websocket delivers the scene meanwhile); with
    ``ready`` (PNG bytes -> bool), again each second until it holds or ``timeout`` ends, for a
    loaded machine that draws slowly. WebGL is drawn on the CPU (SwiftShader), with a fresh
    profile, and no host but 127.0.0.1 resolves: the page must load with no network. Used by
    the tests and scripts/view_screenshots.py (the docs' pictures); no command of the product
    needs it.

    Driven over the DevTools protocol rather than with ``--screenshot``: that one waits for a
    *virtual* time budget, which only runs while the page is idle, and a page fed by a
    websocket seldom is (measured here: 7 s to over 2 min for the same page)."""
    from websockets.sync.client import connect

    exe = find_chromium()
    if exe is None:
        raise FileNotFoundError("no chromium on the PATH (apt-get install chromium)")
    deadline = time.monotonic() + timeout
    # chromium's helper processes may still be writing the profile as it is removed: a leftover
    # folder in /tmp is no reason to fail a screenshot that was taken
    with (
        tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile,
        tempfile.TemporaryFile("w+") as err,
    ):
        cmd = [
            exe,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={profile}",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
            f"--window-size={width},{height}",
            "--remote-debugging-address=127.0.0.1",
            "--remote-debugging-port=0",
            "about:blank",
        ]
        # its own process group, so that stopping it stops its renderer and GPU helpers too
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        returncode = 1
        try:
            port_file = Path(profile) / "DevToolsActivePort"  # chromium writes its port here
            while not (port_file.is_file() and port_file.read_text().strip()):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("chromium did not open its DevTools port")
                time.sleep(0.05)
            port = int(port_file.read_text().split()[0])
            no_proxy = urllib.request.build_opener(urllib.request.ProxyHandler({}))
            targets = json.loads(
                no_proxy.open(f"http://127.0.0.1:{port}/json/list", timeout=10).read()
            )
            page = next(t for t in targets if t.get("type") == "page")
            with connect(
                page["webSocketDebuggerUrl"], proxy=None, max_size=None, open_timeout=10
            ) as ws:
                calls = iter(range(1, 1 << 30))

                def call(method: str, **params) -> dict:
                    n = next(calls)
                    ws.send(json.dumps({"id": n, "method": method, "params": params}))
                    while True:  # events arrive between the answers: skip them
                        msg = json.loads(ws.recv(timeout=max(1.0, deadline - time.monotonic())))
                        if msg.get("id") == n:
                            if "error" in msg:
                                raise RuntimeError(f"{method}: {msg['error']}")
                            return msg.get("result", {})

                call("Page.navigate", url=url)
                time.sleep(wait_ms / 1000)
                png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                while ready is not None and not ready(png) and time.monotonic() + 1 < deadline:
                    time.sleep(1.0)
                    png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
            Path(out).write_bytes(png)
            returncode = 0
        except (OSError, RuntimeError, StopIteration, TimeoutError) as exc:
            err.write(f"\nscreenshot failed: {exc!r}\n")
        finally:
            _stop_group(proc)
            err.seek(0)
            stderr = err.read()
    return subprocess.CompletedProcess(cmd, returncode, "", stderr)


def _stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM to ``proc``'s process group, SIGKILL after 10 s; waits for ``proc``."""
    with contextlib.suppress(ProcessLookupError):  # the whole group may be gone already
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def chromium() -> str:
    """The chromium executable. Missing: a failure in CI (``.ci/run`` installs it, so its
    absence is a broken set-up), a skip that says how to install it elsewhere."""
    exe = find_chromium()
    if exe:
        return exe
    if os.environ.get("CI"):
        pytest.fail("chromium is not installed: .ci/run must apt-get install chromium")
    pytest.skip("needs a headless browser: apt-get install chromium (CI installs it)")


def screenshot(
    url: str, out: Path, width: int = 1000, height: int = 700, wait_ms: int = 3000, check=None
) -> np.ndarray:
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
    assert out.is_file(), (
        f"chromium wrote no screenshot (exit {run.returncode}):\n{run.stderr[-3000:]}"
    )
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
    return float(
        np.mean(
            (img[..., channel] - img[..., others[0]] > margin)
            & (img[..., channel] - img[..., others[1]] > margin)
        )
    )
