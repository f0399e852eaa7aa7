"""``--parent-pid`` (shared/cli_common.py; SIGTERM as Ctrl-C: planner_client/signals.py): a
world, planner or view whose launcher is killed outright (SIGKILL: no handler of the launcher
runs) stops by itself as on Ctrl-C, a kept world with its episode's summary, instead of waiting
for the launcher forever; while the launcher lives, nothing changes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from m3p2i.launch import free_port_block

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/stat").exists(), reason="reads /proc for processes it did not start"
)


def _ended(pid: int) -> bool:
    """Whether process ``pid`` has ended (gone, or a zombie nobody reaped)."""
    try:
        stat = (Path("/proc") / str(pid) / "stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


def _wait(cond, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not cond():
        time.sleep(0.1)
    return cond()


def _launcher(child: list[str], out: Path) -> tuple[subprocess.Popen, int]:
    """A stand-in launcher: a Python process that starts ``child`` (``{pid}`` in it: the
    launcher's own pid; its output to ``out``), prints the child's pid and sleeps. Returns it
    and the child's pid."""
    code = textwrap.dedent(
        f"""
        import os, subprocess, sys, time
        cmd = [a.replace("{{pid}}", str(os.getpid())) for a in {child!r}]
        with open({str(out)!r}, "w") as out:
            child = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
        print(child.pid, flush=True)
        time.sleep(120)
        """
    )
    launcher = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    return launcher, int(launcher.stdout.readline())


def _kill(pid: int) -> None:
    if not _ended(pid):
        subprocess.run(["kill", "-9", str(pid)], check=False)


def _outlives_killed_launcher(cmd: list[str], out: Path, ready: str) -> bool:
    """Start ``cmd`` under a stand-in launcher, wait for ``ready`` in its output, check that
    it runs on while the launcher lives, SIGKILL the launcher: whether ``cmd``'s process still
    runs 20 s later."""
    launcher, pid = _launcher(cmd, out)
    try:
        assert _wait(lambda: ready in out.read_text(), 60.0), out.read_text()
        time.sleep(1.0)
        assert not _ended(pid)
        launcher.send_signal(signal.SIGKILL)
        launcher.wait(10)
        return not _wait(lambda: _ended(pid), 20.0)
    finally:
        _kill(launcher.pid)
        _kill(pid)


def test_a_kept_world_stops_with_its_summary_when_its_launcher_is_killed(tmp_path):
    cmd = [sys.executable, "-m", "server", "--scenario", "navigation"]
    cmd += ["--port", str(free_port_block()), "--keep-serving", "--parent-pid", "{pid}"]
    cmd += ["--log", str(tmp_path / "seed-{seed}.jsonl")]  # a kept world waits for a planner
    assert not _outlives_killed_launcher(cmd, tmp_path / "out", "serving navigation")
    last = json.loads((tmp_path / "seed-0.jsonl").read_text().splitlines()[-1])
    assert last["kind"] == "summary" and last["status"] == "stopped"


@pytest.mark.parametrize(
    "cmd, ready",
    [  # a kept planner waits for a world; a live view serves until stopped
        (["planner_client", "--scenario", "navigation", "--keep-running"], "waiting for a server"),
        (["m3p2i", "view", "navigation", "--view-port", "{page}"], "view: http"),
    ],
    ids=["planner", "view"],
)
def test_a_planner_or_view_stops_when_its_launcher_is_killed(tmp_path, cmd, ready):
    page = str(free_port_block(count=1))
    cmd = [sys.executable, "-m", *(a.replace("{page}", page) for a in cmd)]
    cmd += ["--port", str(free_port_block()), "--parent-pid", "{pid}"]
    assert not _outlives_killed_launcher(cmd, tmp_path / "out", ready)


def test_the_watch_stops_a_process_as_ctrl_c_once_its_parent_is_not_the_one_named():
    code = textwrap.dedent(
        """
        import os, sys, time
        from planner_client.signals import signals_as_ctrl_c
        from shared.cli_common import stop_with_parent
        stop_with_parent(int(sys.argv[1]), every=0.05)
        with signals_as_ctrl_c():
            try:
                time.sleep(30)
            except KeyboardInterrupt as exc:
                print("interrupted:", exc)
        """
    )
    ours = subprocess.run(
        [sys.executable, "-c", code, "1"], capture_output=True, text=True, timeout=20
    )
    assert ours.stdout.strip() == f"interrupted: signal {int(signal.SIGTERM)}", ours.stderr
    # its real parent named: it runs on until stopped
    alive = subprocess.Popen(
        [sys.executable, "-c", code.replace("int(sys.argv[1])", "os.getppid()")],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(1.5)
        assert alive.poll() is None
    finally:
        alive.kill()
        alive.wait(10)


def test_signals_are_the_main_threads_and_come_back_after_the_block():
    """In a thread (a command invoked in-process) nothing is installed, where signal.signal
    would raise and leave the planner's sockets open; in the main thread the handlers before
    the block are back after it."""
    import threading

    from planner_client.signals import signals_as_ctrl_c

    before = signal.getsignal(signal.SIGTERM)
    with signals_as_ctrl_c():
        assert signal.getsignal(signal.SIGTERM) is not before
        seen = []
        worker = threading.Thread(target=lambda: seen.append(_enter_in_thread()))
        worker.start()
        worker.join(10)
        assert seen == ["entered"]
    assert signal.getsignal(signal.SIGTERM) is before


def _enter_in_thread() -> str:
    from planner_client.signals import signals_as_ctrl_c

    with signals_as_ctrl_c():
        return "entered"
