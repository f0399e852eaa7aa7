"""The iteration's split by phase (planner_client.phases): each phase's median over the kept
steps, a step without the phase counting 0, so one stalled step does not move the split."""

from __future__ import annotations

import itertools

import pytest

from planner_client import phases
from planner_client.phases import PhaseClock


@pytest.fixture
def clock(monkeypatch):
    """A PhaseClock whose perf_counter returns the times given to its ``load``."""
    ticks = iter(())

    def load(*values: float) -> None:
        nonlocal ticks
        ticks = itertools.chain(ticks, values)

    monkeypatch.setattr(phases.time, "perf_counter", lambda: next(ticks))
    c = PhaseClock()
    c.load = load
    return c


def _step(clock, **durations):
    t0 = 100.0
    marks = list(itertools.accumulate(durations.values(), initial=t0))
    clock.load(*marks)
    clock.start()
    for phase in durations:
        clock.mark(phase)


def test_the_split_is_each_phases_median_over_the_kept_steps(clock):
    _step(clock, rollout=9.0)  # warm-up: forgotten by keep()
    clock.keep()
    for rollout, costs in [(0.003, 0.001), (0.004, 0.002), (0.5, 0.001)]:  # a stalled rollout
        _step(clock, rollout=rollout, costs=costs)
    _step(clock, rollout=0.002, costs=0.001, map=0.010)  # the map in one step of four
    split = clock.median_ms()
    assert list(split) == ["map", "rollout", "costs"]  # PHASES order
    assert split["rollout"] == pytest.approx(3.5)
    assert split["costs"] == pytest.approx(1.0)
    assert split["map"] == pytest.approx(0.0)  # absent from three steps: they count 0
    assert clock.steps == 4 and clock.totals["rollout"] == pytest.approx(0.509)


def test_without_keep_nothing_is_kept(clock):
    for _ in range(3):
        _step(clock, rollout=0.003)
    assert clock.median_ms() == {}
    assert clock.report() == "rollout 0.009 s"
