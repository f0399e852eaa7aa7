"""Start one episode as two processes, ``python -m server`` and ``python -m planner_client``, on
free loopback ports, and wait for it: what ``m3p2i run``, ``bench`` and ``record`` share.

The two sides still meet only over the wire; this module only starts and stops them.
"""

from __future__ import annotations

import functools
import os
import random
import signal
import socket as pysocket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from server.evaluation import log_reader
from shared.endpoints import DEFAULT_HOST

# Ports this process already handed out: parallel bench trials pick their blocks at the same
# moment, before any server has bound them, so "free right now" alone could give two trials
# overlapping blocks.
_handed_out: set[int] = set()
_ports_lock = threading.Lock()
_random = random.Random()  # its own: tests and planners seed the global one


def free_port_block(host: str = DEFAULT_HOST, count: int = 4) -> int:
    """A base port with ``count`` consecutive free ports on ``host``, never one this process
    handed out before."""
    with _ports_lock:
        base = _find_free_block(host, count)
        _handed_out.update(range(base, base + count))
    return base


def _find_free_block(host: str, count: int) -> int:
    # Below the kernel's ephemeral range: a port picked there ("free right now") can be taken
    # as the source port of any outgoing connection before our server binds it (seen in CI:
    # a planner's diagnostics port in use); below it only listening servers compete.
    low, _ = _ephemeral_range()
    for _ in range(200):
        base = _random.randrange(10000, max(10001, low - count))
        if _handed_out.intersection(range(base, base + count)):
            continue
        if not taken_ports(base, count, host):
            return base
    raise RuntimeError("no block of free ports found")


def taken_ports(first: int, count: int = 1, host: str = DEFAULT_HOST) -> list[int]:
    """The ports of ``first .. first + count - 1`` that cannot be bound on ``host`` now."""
    taken = []
    for p in range(first, first + count):
        with pysocket.socket() as s:
            try:
                s.bind((host, p))
            except OSError:
                taken.append(p)
    return taken


def _ephemeral_range() -> tuple[int, int]:
    """The kernel's range for outgoing connections' source ports (Linux; else IANA's)."""
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(low), int(high)
    except (OSError, ValueError):
        return 49152, 65535


def read_summary(log_path: Path) -> dict | None:
    """The ``summary`` record of an episode log (None when missing or never written)."""
    if not log_path.is_file():
        return None
    return log_reader.summary(log_reader.read_log(log_path))


# The planner's exit codes (planner_client/cli.py): 0 and 1 end an episode (success, not); 2 a
# configuration error, 3 a refused handshake, 4 an uncaught error; a negative one, a signal.
PLANNER_EPISODE_ENDS = (0, 1)
WORLD_ENDS_WITHIN = 20.0
"""Seconds a world may take to end its episode (final states, summary) after its planner ended
it: a planner gone for longer while the world runs left it waiting (lock-step: for ever)."""


@dataclass(frozen=True)
class EpisodeRun:
    """How a launched episode ended. ``reason`` is empty when the world ended it by itself;
    otherwise ``timeout`` (wall clock), ``planner exited with code N`` (a crash, or an end of
    episode the world never followed), ``server exited with code N`` or ``interrupted``.
    :func:`died` names the process of the latter two."""

    log_path: Path
    summary: dict | None
    reason: str
    wall_time: float


@dataclass(frozen=True)
class EpisodeLaunch:
    """What to start: the scenario file, where logs go, and the two processes' options."""

    scenario: str  # a YAML path (both processes load the same file)
    run_dir: Path
    seed: int = 0  # server: randomised start; planner: sampling
    mode: str = "lockstep"
    port: int = 0  # 0: a free block
    timeout: float = 900.0  # wall-clock seconds before both processes are stopped
    threads: int = 0  # planner rollout threads (0: the scenario's / one per core)
    plan_every: int = 1  # lockstep: world steps per command (emulates a slow planner)
    faults: str = ""  # server only: a fault profile or file (docs/faults.md)
    delays: tuple[float, float] | None = None  # planner only: declared (actuation, state) ms
    measure_delays: bool = False  # planner only: measure the delays online
    max_rate: float = 0.0  # planner only: at most this many plans per second (0: no cap)
    realtime_factor: float = 1.0  # server, realtime: world seconds per wall second
    window: bool = False  # server: MuJoCo's own viewer window (a display needed)
    verbose: bool = False  # children write to this terminal instead of log files
    view: bool = False  # serve the browser view (m3p2i view) beside the episode
    view_port: int = 0  # its page's port (0: a free one)
    view_keep: bool = False  # after the episode, the view replays it until interrupted
    keys: Path | None = None  # CURVE key folder (m3p2i keys): both processes use it
    keep_serving: bool = False  # a warm pair (m3p2i.warm): episodes until shut down,
    plugins: tuple[str, ...] = ()  # planner only: --plugins modules of the operator's
    log: str = ""  # each logged to this template ('{seed}' in it)

    @property
    def ports(self) -> int:
        """Consecutive ports the episode uses: the world's three and a diagnostics port per
        planner (a team's robots: one each)."""
        return 3 + max(1, len(team_names(self.scenario)))

    def commands(self, port: int) -> dict[str, list[str]]:
        common = ["--scenario", self.scenario, "--port", str(port), "--seed", str(self.seed)]
        common += ["--parent-pid", str(os.getpid())]  # killed outright, we leave no pair behind
        if self.keys is not None:
            common += ["--keys", str(self.keys)]
        server = [
            sys.executable,
            "-m",
            "server",
            *common,
            "--mode",
            self.mode,
            "--log",
            self.log or str(self.run_dir / "episode.jsonl"),
        ]
        if self.keep_serving:
            server.append("--keep-serving")
        if self.window:
            server.append("--window")
        if self.plan_every != 1:
            server += ["--plan-every", str(self.plan_every)]
        if self.realtime_factor != 1.0:
            server += ["--realtime-factor", repr(self.realtime_factor)]
        if self.faults:  # the planner is not told: it keeps the nominal model
            server += ["--faults", self.faults]
        planner = [sys.executable, "-m", "planner_client", *common]
        if self.keep_serving:
            planner.append("--keep-running")
        if self.threads:
            planner += ["--threads", str(self.threads)]
        if self.max_rate:
            planner += ["--max-rate", repr(self.max_rate)]
        if self.delays is not None:
            planner += [
                "--actuation-delay-ms",
                repr(self.delays[0]),
                "--state-delay-ms",
                repr(self.delays[1]),
            ]
        if self.measure_delays:
            planner.append("--measure-delays")
        for plugin in self.plugins:
            planner += ["--plugins", plugin]
        robots = team_names(self.scenario)
        if not robots:
            return {"server": server, "planner": planner}
        # a team's world: a planner per robot (docs/teams.md)
        return {"server": server} | {f"planner-{r}": [*planner, "--robot", r] for r in robots}

    def view_command(self, port: int, view_port: int) -> list[str]:
        """The browser view of this episode: it also records the planner's diagnostics beside
        the episode log, so that ``m3p2i view --log`` replays the trajectories too."""
        cmd = [
            sys.executable,
            "-m",
            "m3p2i",
            "view",
            self.scenario,
            "--port",
            str(port),
            "--view-port",
            str(view_port),
            "--record",
            str(self.run_dir / "diagnostics.jsonl"),
            "--parent-pid",
            str(os.getpid()),
        ]
        if self.view_keep:  # on SIGUSR1, the same page replays the episode
            cmd += ["--replay-after", str(self.run_dir)]
        return cmd + (["--keys", str(self.keys)] if self.keys is not None else [])


@functools.cache
def team_names(scenario: str) -> tuple[str, ...]:
    """The robots of a team's scenario file, in order (none for a scenario of one robot, or
    one that does not load: the processes report why)."""
    from shared.config import ConfigError
    from shared.scenario import load_scenario

    try:
        return tuple(m.name for m in load_scenario(scenario).team)
    except ConfigError:
        return ()


def run_episode(
    launch: EpisodeLaunch,
    stop: threading.Event | None = None,
    on_view: Callable[[str], None] | None = None,
    on_kept: Callable[[EpisodeRun, str], None] | None = None,
) -> EpisodeRun:
    """Run one episode to its end, its time-out, a planner crash, Ctrl-C or ``stop``; all
    processes are always gone on return (terminated, then killed after 5 s). With
    ``launch.view`` the browser view starts first (so it sees the episode from its first state)
    and ``on_view`` gets its URL once the page is served. With ``launch.view_keep`` too, an
    episode that the world ended by itself leaves the page up: the world and the planner are
    stopped, the view switches to the episode's replay, ``on_kept`` gets the episode's result
    and the URL, and this returns that result on Ctrl-C (or ``stop``, or the view's exit)."""
    launch.run_dir.mkdir(parents=True, exist_ok=True)
    port = launch.port or free_port_block(count=launch.ports)
    log_path = launch.run_dir / "episode.jsonl"
    earlier = _file_stamp(log_path)  # a reused run folder's log: not this episode's
    outs, procs = {}, {}
    reason = ""
    kept: EpisodeRun | None = None
    started = time.monotonic()
    try:
        if launch.view:
            view_port = launch.view_port or free_port_block(count=1)
            _start(launch, "view", launch.view_command(port, view_port), outs, procs)
            url = f"http://{DEFAULT_HOST}:{view_port}/"
            wait_served(url, procs["view"], launch.run_dir / "view.log")
            if on_view is not None:
                on_view(url)
        for name, cmd in launch.commands(port).items():
            _start(launch, name, cmd, outs, procs)
        reason = _watch(procs, started + launch.timeout, stop)
        if launch.view and launch.view_keep and not reason and procs["view"].poll() is None:
            stop_processes([p for name, p in procs.items() if name != "view"])
            kept = EpisodeRun(log_path, read_summary(log_path), "", time.monotonic() - started)
            procs["view"].send_signal(signal.SIGUSR1)  # the page replays the episode
            if on_kept is not None:
                on_kept(kept, url)
            while procs["view"].poll() is None and not (stop is not None and stop.is_set()):
                time.sleep(0.2)
    except KeyboardInterrupt:
        reason = reason if kept else "interrupted"
    finally:
        stop_processes(procs.values())
        for out in outs.values():
            if out is not None:
                out.close()
    if kept is not None:
        return kept
    summary = read_summary(log_path) if _file_stamp(log_path) != earlier else None
    if summary is None and not reason and "server" in procs:
        # a world that failed before its episode began exits 1, as an episode's end does
        reason = f"server exited with code {procs['server'].returncode} without an episode summary"
    return EpisodeRun(log_path, summary, reason, time.monotonic() - started)


def _file_stamp(path: Path) -> tuple[int, int, int] | None:
    """What tells a rewritten file from the one that was there: inode, size, modification."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _start(launch: EpisodeLaunch, name: str, cmd: list[str], outs: dict, procs: dict) -> None:
    """Process ``name`` started with ``cmd``, its output in ``RUN_DIR/NAME.log`` (on the
    terminal with ``launch.verbose``)."""
    out = None if launch.verbose else (launch.run_dir / f"{name}.log").open("w")
    outs[name] = out
    procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if out else None)


def _watch(procs: dict, deadline: float, stop: threading.Event | None) -> str:
    """Wait for the world's end; the reason it ended otherwise ("" when it ended by itself
    with its episode): the time-out, ``stop``, a planner that died (an exit code no episode
    end has) or that ended while the world kept running past :data:`WORLD_ENDS_WITHIN`, or a
    world that died."""
    planner_ended = None  # when a planner exited as at an episode's end
    planners = [name for name in procs if name.startswith("planner")]  # a team's: one each
    while procs["server"].poll() is None:
        if time.monotonic() > deadline:
            return "timeout"
        for name in planners:
            code = procs[name].poll()
            if code is not None and code not in PLANNER_EPISODE_ENDS:
                return f"{name} exited with code {code}"
            if code is not None:
                planner_ended = planner_ended or time.monotonic()
                if time.monotonic() - planner_ended > WORLD_ENDS_WITHIN:
                    return f"{name} exited with code {code}"
        if stop is not None and stop.is_set():
            return "interrupted"
        time.sleep(0.1)
    code = procs["server"].poll()
    if code not in (None, 0, 1):  # 0, 1: its episode's end (success, not)
        return f"server exited with code {code}"
    return ""


def died(reason: str) -> str | None:
    """The process an :class:`EpisodeRun`'s ``reason`` names as exited (``planner`` or
    ``server``), None for a time-out or an interruption."""
    name = reason.split(" ", 1)[0]
    known = name == "server" or name.split("-")[0] == "planner"  # planner-NAME: a team's
    return name if known and " exited with code " in reason else None


def log_tail(path: Path, lines: int = 12) -> list[str]:
    """The last ``lines`` non-empty lines of a process's log (none when it has no log file)."""
    if not path.is_file():
        return []
    with path.open("rb") as f:
        f.seek(max(0, f.seek(0, 2) - 64 * 1024))  # a traceback's end, not a long log's all
        text = f.read().decode("utf-8", "replace")
    return [line for line in text.splitlines() if line.strip()][-lines:]


def wait_served(url: str, proc: subprocess.Popen, log_file: Path, timeout: float = 120.0) -> None:
    """Return once ``url`` answers HTTP 200; RuntimeError if ``proc`` exits first (its log
    named) or after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(
                f"the view exited with code {proc.returncode} before serving "
                f"its page; see {log_file}"
            )
        try:
            with urllib.request.urlopen(url, timeout=2) as reply:
                if reply.status == 200:
                    return
        except (urllib.error.URLError, OSError):
            pass
        time.sleep(0.2)
    raise RuntimeError(f"the view did not serve {url} within {timeout:.0f} s; see {log_file}")


def stop_processes(procs) -> None:
    """Terminate, wait up to 5 s each, then kill: used by the launcher and the tests."""
    procs = list(procs)
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
