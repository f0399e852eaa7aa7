"""``m3p2i run NAME --view`` outlives its episode: once the world has ended it, the same page
serves the episode's replay until Ctrl-C, and the run then exits with the episode's code. Run
from a script (stdout not a terminal) it exits at once, as before."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator

import pytest

from tests.helpers import ENV, _sigint_as_in_a_terminal, stop

pytestmark = pytest.mark.slow
pytest.importorskip("viser")


def _lines(proc: subprocess.Popen) -> queue.Queue:
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    return lines


def _wait_line(
    lines: queue.Queue, prefix: str, proc: subprocess.Popen, seen: list[str], timeout: float
) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        if line.startswith(prefix):
            return line
    raise AssertionError(f"no {prefix!r} line within {timeout:.0f} s:\n" + "".join(seen))


def _inflate(frame: bytes) -> bytes:
    """A websocket frame of viser's, with its zstd-compressed part (if any) decompressed."""
    at = frame.find(b"\x28\xb5\x2f\xfd")  # zstd's magic number
    if at < 0:
        return frame
    import zstandard

    try:
        return frame[:at] + zstandard.ZstdDecompressor().decompressobj().decompress(frame[at:])
    except zstandard.ZstdError:
        return frame


def _page_frames(url: str, seconds: float) -> Iterator[bytes]:
    """Each message the page's websocket sends a new client within ``seconds``, inflated, until
    the page goes."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    with connect(
        url.replace("http://", "ws://"),
        origin=url.rstrip("/"),
        open_timeout=10,
        max_size=None,
        subprotocols=["viser-v1.1.1", "viser"],
    ) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                msg = ws.recv(timeout=max(0.1, end - time.monotonic()))
            except (TimeoutError, ConnectionClosed):  # quiet, or the page ended
                return
            yield _inflate(msg if isinstance(msg, bytes) else msg.encode())


def _page_messages(url: str, seconds: float = 10.0) -> bytes:
    """What the page's websocket sends a new client (the scene and the panel), as raw bytes."""
    got = b""
    for frame in _page_frames(url, seconds):
        got += frame
        if b"time [s]" in got and b"outcome" in got:
            break
    return got


def test_the_page_replays_the_episode_after_it_ends_until_ctrl_c(tmp_path):
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "m3p2i",
            "run",
            "navigation",
            "--view",
            "--view-keep",
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
        preexec_fn=_sigint_as_in_a_terminal,
    )
    seen: list[str] = []
    try:
        lines = _lines(proc)
        url = _wait_line(lines, "view: ", proc, seen, 180).split(" ", 1)[1].strip()
        kept = _wait_line(lines, "episode over; view still at ", proc, seen, 300)
        assert f"view still at {url}: Ctrl-C to quit" in kept
        summary = json.loads((run_dir / "episode.jsonl").read_text().splitlines()[-1])
        assert summary["kind"] == "summary"
        time.sleep(3.0)  # the world and planner are gone by now
        assert proc.poll() is None  # ... and the run waits
        with urllib.request.urlopen(url, timeout=10) as reply:
            assert reply.status == 200
        page = _page_messages(url)
        assert b"time [s]" in page, "no replay time slider on the page"
        assert b"outcome" in page, "no replay outcome on the page"
        assert "replay:" in (run_dir / "view.log").read_text()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(30)
        assert code == (0 if summary["status"] == "success" else 1), "".join(seen)
    finally:
        stop(proc)
