"""How the planner (and ``m3p2i view``, beside it) takes SIGINT and SIGTERM: as Ctrl-C, so
that a supervisor's stop, or the watch of ``--parent-pid``
(:func:`shared.cli_common.stop_with_parent`), ends in the statistics or a closed page. The world
has its own SIGTERM handling (``server/cli.py``). Light to import (no torch): ``m3p2i`` reads it
too."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def signals_as_ctrl_c() -> Iterator[None]:
    """Inside the block, SIGINT and SIGTERM raise KeyboardInterrupt in the main thread, as
    Ctrl-C does in a terminal, whatever the process inherited (a background start ignores
    SIGINT; SIGTERM's default ends the process on the spot, before it says how it did); the
    handlers before it are back after it. Run in another thread (a command invoked in-process,
    as tests do), it changes nothing: a process's signals are its main thread's to take."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
