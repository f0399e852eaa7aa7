"""Soak and fault test (``python scripts/soak.py``, a thin command over this module): real-time
episodes back to back while faults are injected, then checks.

Both processes run on loopback as a user runs them (``python -m server --mode realtime``, one
world process per episode as the server is built, and one ``python -m planner_client
--keep-running`` that plans across them). For ``--duration`` seconds, at seeded random moments
during an episode, one fault at a time, the four kinds in turn (seeded order):

- ``kill``: SIGKILL the planner and start a replacement at once;
- ``restart``: stop the world mid-episode (SIGTERM, as a supervisor does) and start a new one
  on the same ports; the planner must find it by itself;
- ``flood``: push garbage at the command socket from a separate socket: random bytes,
  malformed msgpack, commands of a wrong session, of a wrong shape and with NaN;
- ``pause``: SIGSTOP the planner past the command time-out, then SIGCONT; within the first
  second of an episode, so that the world still has an episode to hold the robot still in.

Checks at the end (exit status 0 only when all hold), printed as a table and written with every
fault and episode to ``soak.json`` next to the episode logs:

- no stale command drove the robot: every step not on the safe control was chosen within
  ``--command-timeout`` of the newest command's arrival (the step record's ``cmd_age``);
- while the planner was dead or paused (from the fault + time-out + ``--slack`` until its next
  command), every logged step was the safe control;
- every killed planner's replacement had a command applied within ``--takeover`` s of its start;
- after every world restart and pause, the planner drove the robot again (within the same bound);
- the world never died: every world process ended its episode by itself or by the deliberate
  SIGTERM, and every episode log is complete, parseable and ends with its summary;
- no garbage or forged command was applied, and every rejectable frame was logged as rejected;
- resident memory (``/proc/PID/status`` VmRSS) of each process grew by at most ``--rss-bound``
  MiB from its first sample after it started driving to its last.

    nice -n 10 python scripts/soak.py --duration 600 --results docs/soak/soak-600s.json
    python scripts/soak.py --report docs/soak/soak-600s.json --update docs/reliability.md

Loopback only, bounded in time (duration + a minute at most) and in faults and episodes.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import msgpack
import numpy as np
import typer
import zmq

from m3p2i.launch import free_port_block, stop_processes
from m3p2i.provenance import machine, versions
from server.evaluation import log_reader
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import find_scenario

from . import netns
from .push_frames import push
from .soak_checks import (  # noqa: F401  (FORGED_CTRL, evaluate, update: the soak's API)
    FORGED_CTRL,
    MIB,
    evaluate,
    first_driven_after,
    markdown,
    print_table,
    rss_growth,
    update,
)

FAULTS = ("kill", "restart", "flood", "pause", "cut")
LOOPBACK_FAULTS = FAULTS[:4]  # ``cut`` needs a link: --netns only
NETNS_PORT = 5555  # the world's namespace is its own: no port is taken there


# ---------------------------------------------------------------- configuration and records


@dataclass(frozen=True)
class SoakConfig:
    """What one soak runs; validated once (:meth:`check`)."""

    duration: float = 600.0  # seconds of faults; the run ends at most a minute later
    seed: int = 0
    scenario: str = "navigation"
    command_timeout: float = 0.5  # the world's --command-timeout
    takeover: float = 3.0  # s from a replacement's start to its first applied command
    slack: float = 0.25  # s after fault + time-out before the safe control must hold
    rss_bound: float = 50.0  # MiB of resident-memory growth allowed per process
    gap: tuple[float, float] = (4.0, 10.0)  # s between faults (uniform)
    flood_frames: int = 50  # frames of each garbage kind per flood
    max_episodes: int = 2000
    netns: bool = False  # world(s) and planner(s) in two network namespaces, CURVE on
    cut_s: float = 2.0  # s the link is down in a ``cut``
    faults: tuple[str, ...] | None = None  # the kinds injected (None: all that apply)

    @property
    def kinds(self) -> tuple[str, ...]:
        """The fault kinds injected, in FAULTS' order."""
        if self.faults is not None:
            return tuple(k for k in FAULTS if k in self.faults)
        return FAULTS if self.netns else LOOPBACK_FAULTS

    def check(self) -> None:
        problems = []
        if not self.duration > 0:
            problems.append(f"--duration must be > 0 s, got {self.duration}")
        if not 0 < self.command_timeout < 5:
            problems.append(f"--command-timeout must be in (0, 5) s, got {self.command_timeout}")
        if not (0 < self.gap[0] <= self.gap[1]):
            problems.append(f"--gap must be 0 < MIN <= MAX, got {self.gap}")
        if self.takeover <= 0 or self.slack < 0 or self.rss_bound <= 0 or self.flood_frames < 1:
            problems.append("--takeover, --rss-bound and --flood-frames must be > 0, --slack >= 0")
        if self.faults is not None:
            unknown = [k for k in self.faults if k not in FAULTS]
            if unknown or not self.faults:
                problems.append(f"--faults must name some of {', '.join(FAULTS)}, got {unknown}")
        if "cut" in self.kinds and not self.netns:
            problems.append("the `cut` fault needs a link to cut: use it with --netns")
        if not 0 < self.cut_s < 30:
            problems.append(f"--cut must be in (0, 30) s, got {self.cut_s}")
        if problems:
            raise typer.BadParameter("; ".join(problems))


@dataclass
class Fault:
    """One injected fault. Wall times are seconds since the epoch (the episode log's ``wall``).
    ``outage`` is when the planner stopped commanding (kill, pause), ``resumed`` when it could
    again (replacement started, SIGCONT, new world started); ``recovered`` is the wall time of
    the first step driven by a command that arrived after ``resumed`` (None: never)."""

    kind: str
    at: float
    world: int  # index of the world process running when it was injected
    outage: float | None = None
    resumed: float | None = None
    recovered: float | None = None
    served: float | None = None  # wall: the world of the recovery step began serving (header)
    detail: dict = field(default_factory=dict)

    @property
    def recovery(self) -> float | None:
        """Seconds to the first step driven again: from the kill itself for a killed planner
        (its hot spare was told to go at once), else from ``resumed``; when that step is in a
        world that started serving later (a restart, or the episode ended meanwhile), from then:
        a world's own cold start is not the planner's."""
        start = self.at if self.kind == "kill" else self.resumed
        if self.recovered is None or start is None:
            return None
        return self.recovered - max(start, self.served if self.served is not None else start)


@dataclass
class Proc:
    """A process of the soak, its resident memory sampled while it runs."""

    role: str  # world | planner
    index: int
    popen: subprocess.Popen
    started: float  # wall
    log: Path | None = None  # world: its episode log
    out: Path | None = None  # its standard output
    active: float | None = None  # wall: a hot spare's go (else its start)
    rss: list[tuple[float, int]] = field(default_factory=list)  # (wall, bytes)
    driving_from: float | None = None  # wall of the first step it drove (memory baseline)
    stopped_on_purpose: bool = False
    returncode: int | None = None

    def sample_rss(self) -> None:
        kb = rss_kib(self.popen.pid)
        if kb is not None and self.popen.poll() is None:
            self.rss.append((time.time(), kb * 1024))


def rss_kib(pid: int) -> int | None:
    """VmRSS of ``pid`` in KiB from /proc (None when gone); psutil is not a dependency."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    return None


def world_record(proc: Proc) -> dict:
    """What the checks need of one world process: its steps, completeness, rejections."""
    try:
        records = log_reader.read_log(proc.log) if proc.log and proc.log.is_file() else []
        parse_error = ""
    except (OSError, UnicodeDecodeError) as exc:
        records, parse_error = [], str(exc)
    with_torn = proc.log.read_text().count("\n") if proc.log and proc.log.is_file() else 0
    steps = log_reader.steps(records)
    summ = log_reader.summary(records)
    complete = (
        not parse_error
        and bool(records)
        and records[0].get("kind") == "header"
        and records[-1].get("kind") == "summary"
        and len(records) == with_torn
        and summ is not None
        and summ.get("steps") == len(steps)
    )
    return {
        "role": "world",
        "index": proc.index,
        "log": str(proc.log),
        "steps": steps,
        "complete": complete,
        "returncode": proc.returncode,
        "stopped_on_purpose": proc.stopped_on_purpose,
        "status": summ.get("status") if summ else None,
        "time": summ.get("time") if summ else None,
        "rejected": summ.get("rejected", 0) if summ else 0,
        "serving_after_s": records[0]["wall"] - proc.started if records else None,
        "rss_growth": rss_growth(proc.rss, proc.driving_from),
    }


# ---------------------------------------------------------------- the run


class LogTail:
    """Complete records appended to an episode log since the last call."""

    def __init__(self, path: Path):
        self.path, self.offset, self.records = path, 0, []

    def poll(self) -> list[dict]:
        if not self.path.is_file():
            return []
        with self.path.open("rb") as f:
            f.seek(self.offset)
            data = f.read()
        end = data.rfind(b"\n") + 1
        self.offset += end
        new = [json.loads(line) for line in data[:end].splitlines() if line.strip()]
        self.records += new
        return new


class Soak:
    def __init__(self, cfg: SoakConfig, out: Path):
        self.cfg, self.out = cfg, out
        self.rng = random.Random(cfg.seed)
        self.scenario = str(find_scenario(cfg.scenario))
        self.port = NETNS_PORT if cfg.netns else free_port_block()
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.worlds: list[Proc] = []
        self.planners: list[Proc] = []
        self.spare: Proc | None = None
        self.closing = False
        self.tails: dict[int, LogTail] = {}
        self.faults: list[Fault] = []
        self.floods = {"floods": 0, "frames": 0, "rejectable": 0, "wrong_session": 0}
        self.ctx = zmq.Context()
        self.hosts: netns.Hosts | None = None  # --netns: set by run()
        self.keys: Path | None = None
        self.pusher: subprocess.Popen | None = None  # --netns: the flood's sender

    @property
    def network(self) -> list[str]:
        """The world's address (and the keys) as both processes are told them."""
        if self.hosts is None:
            return ["--port", str(self.port)]
        return ["--host", self.hosts.world_ip, "--port", str(self.port), "--keys", str(self.keys)]

    # -------------------------------------------------------- processes

    def start_world(self) -> Proc:
        i = len(self.worlds) + 1
        log = self.out / f"episode-{i:04d}.jsonl"
        cmd = [
            sys.executable,
            "-m",
            "server",
            "--scenario",
            self.scenario,
            *self.network,
            "--mode",
            "realtime",
            "--command-timeout",
            str(self.cfg.command_timeout),
            "--seed",
            str(i),
            "--log",
            str(log),
            "--parent-pid",  # a soak killed outright leaves no world behind
            str(os.getpid()),
        ]
        if self.hosts is not None:
            cmd = self.hosts.in_namespace("world", cmd)
        with (self.out / f"world-{i:04d}.out").open("w") as out:
            p = Proc(
                "world",
                i,
                subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=self.env),
                time.time(),
                log,
            )
        p.active = p.started
        self.worlds.append(p)
        self.tails[i] = LogTail(log)
        return p

    def start_planner(self, standby: bool = False) -> Proc:
        """A planner process; ``standby``: a hot spare (``--standby``) that connects when it
        reads a line, started ahead so that a killed planner is replaced without a cold start."""
        i = len(self.planners) + (self.spare is not None) + 1
        cmd = [
            sys.executable,
            "-m",
            "planner_client",
            "--scenario",
            self.scenario,
            *self.network,
            "--keep-running",
            "--seed",
            str(self.cfg.seed + i),
            "--parent-pid",  # kept running: without it, a killed soak's planners ran on forever
            str(os.getpid()),
        ]
        if self.hosts is not None:
            # silence above the cut: the planner keeps its connection through it, and a new
            # world still shows at once (its states carry a new session)
            cmd = self.hosts.in_namespace(
                "planner", [*cmd, "--server-timeout", str(self.cfg.cut_s + 3)]
            )
        path = self.out / f"planner-{i:03d}.out"
        with path.open("w") as out:
            p = Proc(
                "planner",
                i,
                subprocess.Popen(
                    cmd + (["--standby"] if standby else []),
                    stdout=out,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.PIPE if standby else subprocess.DEVNULL,
                    env=self.env,
                ),
                time.time(),
                out=path,
            )
        if standby:
            self.spare = p
        else:
            p.active = p.started
            self.planners.append(p)
        return p

    def spare_ready(self) -> bool:
        return (
            self.spare is not None
            and self.spare.popen.poll() is None
            and "standby: ready" in self.spare.out.read_text()
        )

    def activate_spare(self) -> Proc:
        p, self.spare = self.spare, None
        p.popen.stdin.write(b"go\n")
        p.popen.stdin.flush()
        p.active = time.time()
        self.planners.append(p)
        return p

    @property
    def world(self) -> Proc:
        return self.worlds[-1]

    @property
    def planner(self) -> Proc:
        return self.planners[-1]

    def steps_since(self, since: float) -> list[dict]:
        """Step records of all worlds with wall >= since (logs tailed first)."""
        out = []
        for w in self.worlds:
            tail = self.tails[w.index]
            if w.returncode is not None and tail.records and tail.records[-1]["wall"] < since:
                continue  # ended before ``since``, read to its end
            tail.poll()
            out += [r for r in tail.records if r["kind"] == "step" and r["wall"] >= since]
        return out

    def tick(self) -> None:
        """Housekeeping between faults: memory samples, episodes that ended, processes that
        died unexpectedly (replaced, and counted by the checks)."""
        for p in (self.world, self.planner):
            p.sample_rss()
        for p in (self.world, self.planner):
            if p.driving_from is None:
                first = first_driven_after(self.steps_since(p.active), p.active)
                if first is not None:  # after warm-up (the planner's first iterations allocate)
                    p.driving_from = first["wall"] + (5.0 if p.role == "planner" else 1.0)
        if self.world.popen.poll() is not None and self.world.returncode is None:
            self.world.returncode = self.world.popen.returncode
            if len(self.worlds) < self.cfg.max_episodes and not self.closing:
                self.start_world()
        if self.spare is not None and self.spare.popen.poll() is not None:
            print(
                f"spare planner {self.spare.index} exited with code "
                f"{self.spare.popen.returncode}; starting another",
                file=sys.stderr,
            )
            self.spare.returncode = self.spare.popen.returncode
            self.planners.append(self.spare)  # counted: its log is kept, it never drove
            self.spare = None
            self.start_planner(standby=True)
        if self.planner.popen.poll() is not None:
            self.planner.returncode = self.planner.popen.returncode
            print(
                f"planner {self.planner.index} exited by itself with code "
                f"{self.planner.returncode}; starting another",
                file=sys.stderr,
            )
            self.start_planner()

    def mid_episode(self, within: float | None = None) -> bool:
        """The current world is stepping under the planner's commands (with ``within``: and
        began stepping less than ``within`` s ago)."""
        tail = self.tails[self.world.index]
        tail.poll()
        recs = tail.records
        if self.world.popen.poll() is not None or not recs or recs[-1]["kind"] == "summary":
            return False
        steps = [r for r in recs[-20:] if r["kind"] == "step"]
        if not steps or steps[-1]["safe"] or time.time() - steps[-1]["wall"] >= 0.5:
            return False
        first = next(r for r in recs if r["kind"] == "step")
        return within is None or time.time() - first["wall"] < within

    def wait(self, seconds: float, until=None) -> bool:
        """Tick for ``seconds`` or until ``until()`` holds."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.tick()
            if until is not None and until():
                return True
            time.sleep(0.05)
        return False

    # -------------------------------------------------------- faults

    def inject(self, kind: str) -> Fault:
        f = Fault(kind, time.time(), self.world.index)
        if kind == "kill":
            old = self.planner
            old.popen.send_signal(signal.SIGKILL)
            old.popen.wait()
            old.returncode, old.stopped_on_purpose = old.popen.returncode, True
            f.outage = f.at
            f.resumed = self.activate_spare().active
        elif kind == "pause":
            duration = self.cfg.command_timeout + self.rng.uniform(0.3, 1.5)
            self.planner.popen.send_signal(signal.SIGSTOP)
            f.outage = time.time()
            self.wait(duration)
            self.planner.popen.send_signal(signal.SIGCONT)
            f.resumed = time.time()
            f.detail["paused_s"] = round(f.resumed - f.outage, 3)
        elif kind == "restart":
            old = self.world
            old.stopped_on_purpose = True
            old.popen.send_signal(signal.SIGTERM)
            try:
                old.popen.wait(15)
            except subprocess.TimeoutExpired:
                f.detail["error"] = "the world did not stop within 15 s of SIGTERM"
                old.popen.kill()
                old.popen.wait()
            old.returncode = old.popen.returncode
            f.resumed = self.start_world().started
        elif kind == "flood":
            f.detail.update(self.flood())
            f.resumed = time.time()
        elif kind == "cut":
            f.outage, f.resumed = self.hosts.cut(self.cfg.cut_s, wait=self.wait)
            f.detail["cut_s"] = round(f.resumed - f.outage, 3)
        self.faults.append(f)
        return f

    def flood(self) -> dict:
        """Garbage at the command socket from a socket of our own; counts what was sent."""
        n = self.cfg.flood_frames
        header = self.tails[self.world.index].records[0]
        session, nu = header["session"], header["nu"]
        bad_session = "x" + session[1:] if session[0] != "x" else "y" + session[1:]
        frames = []
        frames += [self.rng.randbytes(self.rng.randint(1, 2000)) for _ in range(n)]
        frames += [msgpack.packb(m) for m in self._malformed(n, session)]
        frames += [
            P.encode(P.Command(session=session, seq=0, ctrl=np.zeros(nu + 1 + k % 3)))
            for k in range(n)
        ]  # wrong shape, right session
        forged = [
            P.encode(P.Command(session=bad_session, seq=0, ctrl=np.array(FORGED_CTRL[:nu])))
            for _ in range(n)
        ]
        if self.hosts is None:
            push(self.ctx, Endpoints(port=self.port).command, frames + forged)
        else:  # from the planner's namespace, with its keys (scripts.measure.push_frames)
            path = self.out / f"flood-{self.floods['floods'] + 1:03d}.msgpack"
            path.write_bytes(msgpack.packb(frames + forged))
            self.pusher.stdin.write(f"{path}\n")
            self.pusher.stdin.flush()
            said = self.pusher.stdout.readline().strip()
            if not said.startswith("sent"):
                raise RuntimeError(f"the flood from the planner's namespace: {said or 'no answer'}")
        self.floods["floods"] += 1
        self.floods["frames"] += len(frames) + len(forged)
        self.floods["rejectable"] += len(frames)
        self.floods["wrong_session"] += len(forged)
        return {"frames": len(frames) + len(forged), "rejectable": len(frames)}

    def _malformed(self, n: int, session: str) -> list:
        """msgpack that decodes but is no valid message: every kind of field error."""
        base = {"type": "command", "v": P.PROTOCOL_VERSION, "session": session, "seq": 0}
        arr = P.encode_array(np.zeros(2))
        kinds = [
            [1, 2, 3],  # not a map
            {"type": "nonsense", "v": P.PROTOCOL_VERSION},  # unknown type
            {**base, "ctrl": arr, "v": 99},  # wrong version
            {**base},  # ctrl missing
            {**base, "ctrl": "fast"},  # ctrl not an array
            {**base, "ctrl": {**arr, "data": b"\x00" * 3}},  # byte count
            {**base, "ctrl": {**arr, "dtype": "object"}},  # dtype
            {**base, "ctrl": P.encode_array(np.array([np.nan, 0.0]))},  # NaN
            {**base, "ctrl": arr, "extra": 1},  # unknown field
            {**base, "ctrl": arr, "seq": "zero"},  # seq not an int
            {
                **base,
                "ctrl": arr,
                "plan_ctrl": P.encode_array(np.zeros((3, 5))),
                "plan_t0": 0.0,
                "plan_dt": 0.05,
            },  # plan of the wrong width
        ]
        return [kinds[k % len(kinds)] for k in range(n)]

    def await_recovery(self, f: Fault) -> None:
        """Wait (bounded) for the first step driven by a command sent after ``f.resumed``."""
        limit = self.cfg.takeover + 30.0
        since = f.resumed

        def recovered() -> bool:
            for w in self.worlds[f.world - 1 :]:  # in the order they ran
                tail = self.tails[w.index]
                tail.poll()
                s = first_driven_after([r for r in tail.records if r["kind"] == "step"], since)
                if s is not None:
                    f.recovered, f.served = s["wall"], tail.records[0]["wall"]
                    f.detail["plan_age"] = round(s.get("age", 0.0), 3)  # of its state
                    return True
            return False

        self.wait(limit, recovered)

    # -------------------------------------------------------- main

    def run(self) -> dict:
        """The soak; with ``--netns`` inside two namespaces made for it and always removed
        (:func:`scripts.measure.netns.two_hosts`; :class:`netns.Unavailable` where not permitted)
        and with CURVE keys made once into ``OUT/keys``."""
        self.out.mkdir(parents=True, exist_ok=True)
        if not self.cfg.netns:
            return self._run()
        self.keys = self.out / "keys"
        if self.keys.exists():
            shutil.rmtree(self.keys)  # this soak's own, from an earlier run into the same OUT
        subprocess.run(
            [sys.executable, "-m", "m3p2i", "keys", str(self.keys)],
            check=True,
            capture_output=True,
            env=self.env,
            timeout=60,
        )
        with netns.two_hosts() as hosts:
            self.hosts = hosts
            endpoint = Endpoints(hosts.world_ip, self.port).command
            cmd = [
                sys.executable,
                str(Path(__file__).with_name("push_frames.py")),
                endpoint,
                str(self.keys),
            ]
            self.pusher = subprocess.Popen(
                hosts.in_namespace("planner", cmd),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env=self.env,
            )
            try:
                if self.pusher.stdout.readline().strip() != "ready":
                    raise RuntimeError(
                        "the flood's sender in the planner's namespace did not start"
                    )
                return self._run()
            finally:
                stop_processes([self.pusher])
                self.hosts = None

    def _run(self) -> dict:
        started = time.time()
        self.start_world()
        self.start_planner()
        order: list[str] = []
        end = time.monotonic() + self.cfg.duration
        hard_end = end + 60.0
        try:
            self.wait(120.0, self.mid_episode)  # first start: imports, compilation
            self.start_planner(standby=True)
            while time.monotonic() < end:
                self.wait(min(self.rng.uniform(*self.cfg.gap), max(0.0, end - time.monotonic())))
                if time.monotonic() >= end:
                    break
                if not order:
                    order = list(self.cfg.kinds)
                    self.rng.shuffle(order)
                kind = order.pop()
                if kind == "kill" and not self.wait(120.0, self.spare_ready):
                    print("the spare planner never became ready", file=sys.stderr)
                    break
                # "at a random moment" of an episode: the planner must be driving the robot. A
                # pause (and a cut) early in it: one near its end let the robot coast into the
                # goal on its last command, and the world that holds still was never seen (no
                # step left to log between the time-out and the episode's end)
                within = 1.0 if kind in ("pause", "cut") else None
                if not self.wait(
                    min(30.0, hard_end - time.monotonic()),
                    lambda within=within: self.mid_episode(within),
                ):
                    break
                f = self.inject(kind)
                print(f"{time.time() - started:7.1f} s  {kind:8s} world {f.world}", flush=True)
                self.await_recovery(f)
                if self.spare is None:
                    self.start_planner(standby=True)
            self.closing = True
            self.wait(
                min(40.0, max(0.0, hard_end - time.monotonic())),
                lambda: self.world.popen.poll() is not None,
            )  # let the last episode end
        finally:
            self.closing = True
            procs = [self.world, self.planner] + ([self.spare] if self.spare else [])
            for p in procs:
                if p.popen.poll() is None:
                    p.stopped_on_purpose = True
            stop_processes([p.popen for p in procs])  # SIGTERM: the world writes its summary
            if self.spare is not None:
                self.spare.returncode = self.spare.popen.returncode
                self.planners.append(self.spare)
            for p in self.worlds + self.planners:
                if p.returncode is None:
                    p.returncode = p.popen.returncode
            self.ctx.term()
        return self.results(started)

    def results(self, started: float) -> dict:
        worlds = [world_record(w) for w in self.worlds]
        planners = [
            {
                "role": "planner",
                "index": p.index,
                "returncode": p.returncode,
                "stopped_on_purpose": p.stopped_on_purpose,
                "rss_first_mib": p.rss[0][1] / MIB if p.rss else None,
                "rss_last_mib": p.rss[-1][1] / MIB if p.rss else None,
                "lived_s": (p.rss[-1][0] - p.started) if p.rss else 0.0,
                "rss_growth": rss_growth(p.rss, p.driving_from),
            }
            for p in self.planners
        ]
        checks = evaluate(self.cfg, self.faults, worlds, planners, self.floods)
        statuses: dict[str, int] = {}
        for w in worlds:
            statuses[str(w["status"])] = statuses.get(str(w["status"]), 0) + 1
        counts = {
            k: {
                "injected": sum(f.kind == k for f in self.faults),
                "survived": sum(
                    f.kind == k and f.recovery is not None and f.recovery <= self.cfg.takeover
                    for f in self.faults
                ),
            }
            for k in self.cfg.kinds
        }
        return {
            "config": {**asdict(self.cfg), "gap": list(self.cfg.gap)},
            "command": "python scripts/soak.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(started)),
            "wall_s": round(time.time() - started, 1),
            "machine": machine(),
            "versions": versions(),
            "ok": all(c.ok for c in checks),
            "checks": [asdict(c) for c in checks],
            "faults": counts,
            "fault_log": [{**asdict(f), "recovery": f.recovery} for f in self.faults],
            "episodes": statuses,
            "steps": sum(len(w["steps"]) for w in worlds),
            "worlds": [{k: v for k, v in w.items() if k != "steps"} for w in worlds],
            "planners": planners,
        }
