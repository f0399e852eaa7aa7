"""The load harness (m3p2i/load.py): its busy processes run while asked, stop when told, stop by
themselves at their deadline and when the process that started them is killed, so neither a test
nor a killed command leaves load behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from m3p2i.load import BusyLoad


def _wait_until(cond, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def test_busy_processes_run_inside_the_block_and_stop_at_its_end():
    with BusyLoad(2, max_seconds=60) as load:
        assert load.alive() == 2
        pids = [w.pid for w in load._workers]
    assert load.alive() == 0 and all(p is not None for p in pids)


def test_busy_processes_stop_by_themselves_at_their_deadline():
    load = BusyLoad(1, max_seconds=0.5).start()
    try:
        assert _wait_until(lambda: load.alive() == 0, 20.0)
    finally:
        load.stop()


@pytest.mark.parametrize("procs, seconds", [(-1, 1.0), (65, 1.0), (1, 0.0), (1, float("nan"))])
def test_a_load_out_of_bounds_is_refused(procs, seconds):
    with pytest.raises(ValueError, match="expected"):
        BusyLoad(procs, max_seconds=seconds)


def _children(pid: int) -> list[int]:
    """Live processes whose parent is ``pid`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and _state(int(entry.name)) not in ("", "Z"):
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid:
                found.append(int(entry.name))
    return found


def _state(pid: int) -> str:
    """A process's state letter ('Z': a zombie, done but not reaped), '' when it is gone."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return ""


def _cmdline(pid: int) -> bytes:
    """A process's command line, b"" when it ended between listing /proc and reading it."""
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes()
    except OSError:
        return b""


def _gone(pids: list[int]) -> bool:
    return all(_state(p) in ("", "Z") for p in pids)


def _load_command(procs: int) -> tuple[subprocess.Popen, list[int]]:
    """``python -m m3p2i.load`` with ``procs`` busy processes, and the pids of those (not of
    multiprocessing's resource tracker), once they run."""
    cmd = [sys.executable, "-m", "m3p2i.load", "--procs", str(procs), "--seconds", "60"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    busy: list[int] = []

    def started() -> bool:
        busy[:] = [p for p in _children(proc.pid) if b"spawn_main" in _cmdline(p)]
        return len(busy) == procs

    if not _wait_until(started, 30.0):
        proc.kill()
        pytest.fail(f"{procs} busy processes did not start: {proc.communicate()[0]}")
    return proc, busy


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc (Linux)")
def test_busy_processes_stop_when_the_command_that_started_them_is_killed():
    proc, busy = _load_command(2)
    try:
        proc.kill()  # SIGKILL: no handler runs, the harness cannot stop them itself
        proc.wait(10)
        assert _wait_until(lambda: _gone(busy), 10.0), "busy processes outlived their starter"
    finally:
        _kill_left(busy)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc (Linux)")
def test_sigterm_stops_the_load_command_as_ctrl_c_does():
    proc, busy = _load_command(1)
    try:
        proc.terminate()
        out, _ = proc.communicate(timeout=15)
        assert proc.returncode == 0 and "stopped" in out, out
        assert _wait_until(lambda: _gone(busy), 10.0)
    finally:
        _kill_left(busy)


def _kill_left(pids: list[int]) -> None:
    """A failing test leaves no load behind either."""
    for p in pids:
        if not _gone([p]):
            os.kill(p, signal.SIGKILL)
