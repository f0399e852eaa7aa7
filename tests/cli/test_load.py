"""The load harness (scripts/measure/load.py): its busy processes run while asked, stop when
told, and stop by themselves at their deadline, so a test never leaves load behind."""

from __future__ import annotations

import time

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
