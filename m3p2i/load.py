"""Repeatable load: N busy processes that compete with the planner for the cores, as a robot's
computer also runs drivers, perception and logging. Each spins on arithmetic until the harness
stops it, its own deadline passes or the process that started it is gone (killed, even with
SIGKILL), so a crashed caller never leaves load behind.

    with BusyLoad(2, max_seconds=900):       # two cores' worth of competition
        run_the_episodes()

A bench case's ``load: N`` runs its trials under it (:mod:`m3p2i.bench`), and
``python -m m3p2i.load --procs 2 --seconds 60`` loads the machine from a shell, e.g. beside
``m3p2i run``.

A busy process runs at the default nice level, as the planner does: the scheduler shares the
cores between them, which is the point.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from multiprocessing.synchronize import Event
from types import TracebackType
from typing import Annotated

import typer

MAX_PROCS = 64
MAX_SECONDS = 24 * 3600.0


def _spin(stop: Event, deadline: float, parent: int) -> None:
    """Burn one core until ``stop`` is set, the monotonic ``deadline`` passes or process
    ``parent`` is no longer this one's parent (it died: the orphan was adopted)."""
    x = 0
    while time.monotonic() < deadline and not stop.is_set() and os.getppid() == parent:
        for _ in range(20_000):  # a slice of pure work between checks: ~1 ms
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


class BusyLoad:
    """``procs`` busy processes, started on ``__enter__`` (or :meth:`start`) and stopped on
    ``__exit__`` (or :meth:`stop`); each also stops by itself after ``max_seconds``."""

    def __init__(self, procs: int, max_seconds: float = 600.0):
        if not 0 <= procs <= MAX_PROCS:
            raise ValueError(f"procs {procs}: expected 0 to {MAX_PROCS} busy processes")
        if not 0 < max_seconds <= MAX_SECONDS:
            raise ValueError(f"max_seconds {max_seconds}: expected (0, {MAX_SECONDS:g}] s")
        self.procs, self.max_seconds = procs, max_seconds
        self._ctx = mp.get_context("spawn")  # no fork of a caller's threads (torch, zmq)
        self._stop = self._ctx.Event()
        self._workers: list[mp.process.BaseProcess] = []

    def start(self) -> BusyLoad:
        """Start the busy processes (their deadline counted from now)."""
        if self._workers:
            raise RuntimeError("this load has been started already")
        # time.monotonic is system-wide on Linux: the children compare against the same clock
        deadline = time.monotonic() + self.max_seconds
        for i in range(self.procs):
            w = self._ctx.Process(
                target=_spin,
                args=(self._stop, deadline, os.getpid()),
                daemon=True,
                name=f"busy-{i}",
            )
            w.start()
            self._workers.append(w)
        return self

    def alive(self) -> int:
        """How many busy processes run now."""
        return sum(w.is_alive() for w in self._workers)

    def stop(self, timeout: float = 5.0) -> None:
        """Stop them, killing any that has not stopped within ``timeout`` s."""
        self._stop.set()
        for w in self._workers:
            w.join(timeout)
            if w.is_alive():
                w.kill()
                w.join(timeout)

    def __enter__(self) -> BusyLoad:
        return self.start()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def main(
    procs: Annotated[int, typer.Option(min=0, max=MAX_PROCS, help="Busy processes.")] = 2,
    seconds: Annotated[
        float, typer.Option(min=0.001, max=MAX_SECONDS, help="How long they run.")
    ] = 60.0,
) -> None:
    """Load the machine with PROCS busy processes for SECONDS (Ctrl-C or SIGTERM stops them
    sooner; they also stop if this process is killed)."""
    from m3p2i.cli_support import terminate_as_interrupt

    terminate_as_interrupt()
    typer.echo(f"{procs} busy processes for {seconds:g} s on {os.cpu_count()} cores")
    with BusyLoad(procs, max_seconds=seconds) as load:
        try:
            while load.alive():
                time.sleep(0.2)
        except KeyboardInterrupt:
            typer.echo("stopped")


if __name__ == "__main__":
    typer.run(main)
