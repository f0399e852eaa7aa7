"""Warm bench workers: one server + planner pair kept across the trials of a bench case.

A fresh pair per trial pays both processes' start-up (imports, model compilation: ~2.5-4.7 s)
for episodes of 3-30 s. A warm pair is started once (``m3p2i-server --keep-serving`` and
``m3p2i-planner --keep-running``); each later trial begins with a control ``reset`` carrying its
seed. The world then builds a fresh world for that seed, under a new session, with its own
episode log; the planner, seeing the new session, rebuilds its planner and task layer with the
seed the welcome carries. Nothing of one episode reaches the next, so a lock-step trial gives
the same result as a fresh pair with the same seed on the same machine (tests/cli/test_bench.py).

The pair's own process logs stay in ``logs/CASE/pairs/seed-NNN/`` (NNN: the pair's first seed);
each trial's folder gets the part of them written during the trial, as ``server.log`` and
``planner.log``, as with a fresh pair. A trial that times out, crashes or is interrupted takes
its pair down with it; the next trial starts a new one.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import threading
import time
from pathlib import Path

import zmq

from m3p2i.launch import (
    EpisodeLaunch,
    EpisodeRun,
    free_port_block,
    read_summary,
    stop_processes,
)
from server.evaluation.log_reader import episode_log_path, has_summary
from shared import protocol as P
from shared.endpoints import DEFAULT_HOST, Endpoints, socket

_CONTROL_TIMEOUT = 10.0  # s for the world to answer a reset (it may be finishing a step)


class WarmPair:
    """The processes of one bench case, started by the first trial that needs them.

    ``launch`` gives the scenario, mode, threads and where the pair's process logs go
    (``run_dir``); ``log`` is the episode log template, ``{seed}`` in it."""

    def __init__(self, launch: EpisodeLaunch):
        if "{seed" not in launch.log:
            raise ValueError(f"a warm pair's episode log needs '{{seed}}' in it: {launch.log!r}")
        self.launch = dataclasses.replace(launch, keep_serving=True)
        self.procs: dict[str, subprocess.Popen] = {}
        self._outs: dict[str, object] = {}
        self._port = 0

    @property
    def alive(self) -> bool:
        return bool(self.procs) and all(p.poll() is None for p in self.procs.values())

    def run(self, seed: int, timeout: float, stop: threading.Event | None = None) -> EpisodeRun:
        """One episode from ``seed``: the pair's first (it starts the processes), or the next
        one begun by a reset. Returns as :func:`m3p2i.launch.run_episode` does."""
        log_path = episode_log_path(self.launch.log, seed)
        shutil.rmtree(log_path.parent, ignore_errors=True)  # a stale attempt's log must not count
        log_path.parent.mkdir(parents=True)
        names = launch_names(self.launch)
        marks = {name: self._size(name) for name in names}
        started = time.monotonic()
        reason = ""
        try:
            if self.alive:
                self._reset(seed)
            else:
                self.close()
                self._start(seed)
            reason = self._wait(log_path, started, timeout, stop)
        except KeyboardInterrupt:
            reason = "interrupted"
        except RuntimeError as exc:  # the world refused or ignored the reset
            reason = str(exc)
        if reason:
            self.close()  # its logs are complete once the processes are gone
        self._copy_logs(marks, log_path.parent)
        return EpisodeRun(
            log_path=log_path,
            summary=read_summary(log_path),
            reason=reason,
            wall_time=time.monotonic() - started,
        )

    def close(self) -> None:
        """Stop both processes (the world writes the running episode's summary on SIGTERM)."""
        stop_processes(self.procs.values())
        for out in self._outs.values():
            out.close()
        self.procs, self._outs = {}, {}

    # ------------------------------------------------------------------ internals

    def _start(self, seed: int) -> None:
        folder = self.launch.run_dir
        folder.mkdir(parents=True, exist_ok=True)
        self._port = free_port_block(count=self.launch.ports)
        launch = dataclasses.replace(self.launch, seed=seed)
        for name, cmd in launch.commands(self._port).items():
            out = (folder / f"{name}.log").open("a")
            self._outs[name] = out
            self.procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)

    def _reset(self, seed: int) -> None:
        """Ask the world for the next episode; RuntimeError when it refuses or stays silent."""
        ctx = zmq.Context.instance()
        req = socket(ctx, zmq.REQ)
        try:
            req.connect(Endpoints(DEFAULT_HOST, self._port).control)
            req.send(P.encode(P.Control(op="reset", seed=seed)))
            if not req.poll(int(_CONTROL_TIMEOUT * 1000)):
                raise RuntimeError(
                    f"the world did not answer the reset to seed {seed} "
                    f"within {_CONTROL_TIMEOUT:.0f} s"
                )
            reply = P.decode(req.recv(), expect=("control", "error"))
        except P.ProtocolError as exc:
            raise RuntimeError(f"the world's answer to the reset is invalid: {exc}") from None
        finally:
            req.close(0)
        if isinstance(reply, P.Error):
            raise RuntimeError(f"the world refused the reset to seed {seed}: {reply.reason}")

    def _wait(
        self, log_path: Path, started: float, timeout: float, stop: threading.Event | None
    ) -> str:
        """'' once the episode's summary is written; else why not (as run_episode says it)."""
        while not has_summary(log_path):
            server = self.procs["server"].poll()
            if server is not None:
                # it may have written the summary just before exiting
                return "" if has_summary(log_path) else f"server exited with code {server}"
            for name, proc in self.procs.items():
                if name != "server" and proc.poll() is not None:
                    return f"{name} exited with code {proc.poll()}"
            if time.monotonic() - started > timeout:
                return "timeout"
            if stop is not None and stop.is_set():
                return "interrupted"
            time.sleep(0.05)
        return ""

    def _size(self, name: str) -> int:
        path = self.launch.run_dir / f"{name}.log"
        return path.stat().st_size if path.is_file() else 0

    def _copy_logs(self, marks: dict[str, int], folder: Path) -> None:
        """The part of each process log written since ``marks`` (offsets), into ``folder``."""
        for name, offset in marks.items():
            src = self.launch.run_dir / f"{name}.log"
            if src.is_file():
                with src.open("rb") as f:
                    f.seek(offset)
                    (folder / f"{name}.log").write_bytes(f.read())


def launch_names(launch: EpisodeLaunch) -> list[str]:
    """The processes of a launch: ``server``, and ``planner`` or a team's ``planner-NAME``."""
    return list(launch.commands(0))


class PairSlot:
    """A worker's one warm pair, replaced when a trial of another case comes."""

    def __init__(self):
        self.key: object = None
        self.pair: WarmPair | None = None

    def get(self, key: object, launch: EpisodeLaunch) -> WarmPair:
        if self.pair is None or key != self.key:
            self.close()
            self.key, self.pair = key, WarmPair(launch)
        return self.pair

    def close(self) -> None:
        if self.pair is not None:
            self.pair.close()
        self.key, self.pair = None, None
