"""An anytime planner: the samples per mode follow a declared time budget (``planner.budget``).

When the computer is busy an iteration takes longer, the plans age, and a real-time world plays
them late. With a budget of ``rate`` iterations a second the planner measures its iterations and
sheds samples (every mode alike, never below ``min_samples``) when they overrun 1/``rate``, and
takes them back when the time allows, so that its plans stay young. The rollout dominates an
iteration and costs in proportion to the samples, so the count that fits is the budget over the
measured seconds per sample (their running mean): shed at once, grown back only after
``patience`` iterations in a row had room, and in steps of a twentieth of the full count, so
the count settles rather than following every noisy iteration.

The budget applies against a real-time world only (the controller makes it at ``begin``): in
lock-step the world waits for every plan, so a scenario's budget leaves its lock-step episodes
as they are, its seed's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shared.config import Section, positive, positive_int
from shared.scenario import Scenario

HEADROOM = 0.85  # of the period an iteration may fill: the rest absorbs its noise
SMOOTHING = 0.3  # weight of the newest iteration in the running seconds per sample


@dataclass(frozen=True)
class BudgetConfig:
    """``planner.budget``: ``rate`` iterations a second to keep (Hz > 0), ``min_samples`` per
    mode never to shed below, ``patience`` iterations with room before samples come back."""

    rate: float
    min_samples: int
    patience: int = 5


def budget_config(scenario: Scenario) -> BudgetConfig | None:
    """``planner.budget`` read and checked; None when the scenario has none."""
    raw = scenario.planner.budget
    if not raw:
        return None
    s = Section(raw, scenario.source, "planner.budget")
    samples = scenario.planner.samples
    # a mode needs its best and null rows and at least eta_l samples (planner_client.mppi)
    eta = scenario.planner.mppi.eta_bounds
    least = max(3, math.ceil(eta[0]) if eta is not None else 0)
    cfg = BudgetConfig(
        rate=s.req("rate", positive, "iterations a second > 0"),
        min_samples=s.opt(
            "min_samples",
            min(samples, max(samples // 4, least)),
            _int_in(least, samples),
            f"an integer in [{least}, planner.samples = {samples}]",
        ),
        patience=s.opt("patience", BudgetConfig.patience, positive_int, "an integer >= 1"),
    )
    s.done()
    return cfg


def _int_in(lo: int, hi: int):
    """A converter for an integer in ``[lo, hi]``."""

    def convert(value):
        if positive_int(value) < lo or value > hi:
            raise ValueError(f"must be in [{lo}, {hi}]")
        return value

    return convert


@dataclass(frozen=True)
class Change:
    """A change of the samples per mode: from ``before`` to ``after``, and why."""

    before: int
    after: int
    reason: str


class SampleBudget:
    """The samples per mode under ``cfg``, starting from (and never above) ``full``: feed it
    each iteration's seconds with :meth:`observe`."""

    def __init__(self, cfg: BudgetConfig, full: int):
        self.cfg, self.full = cfg, full
        self.samples = full
        self.step = max(1, full // 20)
        self.per_sample: float | None = None  # running seconds per sample
        self._room = 0  # iterations in a row that had room for more

    @property
    def period(self) -> float:
        """The budget of an iteration, s."""
        return 1.0 / self.cfg.rate

    def observe(self, seconds: float) -> Change | None:
        """An iteration of the current count took ``seconds``: the new count when it changes
        (:attr:`samples` is then the new one), else None."""
        if not (math.isfinite(seconds) and seconds > 0):
            return None
        rate = seconds / self.samples
        old = rate if self.per_sample is None else self.per_sample
        self.per_sample = (1 - SMOOTHING) * old + SMOOTHING * rate
        fits = HEADROOM * self.period / self.per_sample
        if seconds > self.period and self.samples > self.cfg.min_samples:
            self._room = 0
            after = max(self.cfg.min_samples, min(self.samples - self.step, self._quantise(fits)))
            ms, budget = seconds * 1e3, self.period * 1e3
            return self._set(after, f"iteration {ms:.0f} ms over the budget of {budget:.0f} ms")
        if fits >= self.samples + self.step and self.samples < self.full:
            self._room += 1
            if self._room >= self.cfg.patience:
                self._room = 0
                after = min(self.full, self.samples + self.step)
                return self._set(after, f"{self.cfg.patience} iterations with room in the budget")
            return None
        self._room = 0
        return None

    def _quantise(self, n: float) -> int:
        return int(n // self.step) * self.step

    def _set(self, after: int, reason: str) -> Change | None:
        if after == self.samples:
            return None
        change = Change(self.samples, after, reason)
        self.samples = after
        return change
