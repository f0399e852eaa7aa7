"""An anytime planner: the samples per mode, then the horizon, follow a declared time budget
(``planner.budget``).

When the computer is busy an iteration takes longer, the plans age, and a real-time world plays
them late. With a budget of ``rate`` iterations a second the planner measures its iterations and
sheds samples (every mode alike, never below ``min_samples``) when they overrun 1/``rate``; at
its fewest samples it sheds horizon steps (never below ``min_horizon``); it takes them back,
steps first, when the time allows, so that its plans stay young. The rollout dominates an
iteration and costs in proportion to samples x steps, so what fits is the budget over the
measured seconds per sample-step (their running mean): shed at once, grown back only after
``patience`` iterations in a row had room, a twentieth of the samples or one step at a time,
so the count settles rather than following every noisy iteration.

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
    mode and ``min_horizon`` steps never to shed below, ``patience`` iterations with room
    before samples or steps come back."""

    rate: float
    min_samples: int
    min_horizon: int
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
    # the plan must still hold the smoothing window (planner.mppi.savgol_window) and two steps
    horizon = scenario.planner.horizon
    shortest = min(horizon, max(2, scenario.planner.mppi.savgol_window or 0))
    cfg = BudgetConfig(
        rate=s.req("rate", positive, "iterations a second > 0"),
        min_samples=s.opt(
            "min_samples",
            min(samples, max(samples // 4, least)),
            _int_in(least, samples),
            f"an integer in [{least}, planner.samples = {samples}]",
        ),
        min_horizon=s.opt(
            "min_horizon",
            max(shortest, horizon // 2),
            _int_in(shortest, horizon),
            f"an integer in [{shortest}, planner.horizon = {horizon}]",
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
    """A change of ``what`` (``samples`` per mode, or ``horizon`` steps) from ``before`` to
    ``after``, and why."""

    what: str
    before: int
    after: int
    reason: str


class SampleBudget:
    """The samples per mode and the horizon under ``cfg``, starting from (and never above)
    ``full`` samples and ``horizon`` steps: feed it each iteration's seconds with
    :meth:`observe`."""

    def __init__(self, cfg: BudgetConfig, full: int, horizon: int):
        self.cfg, self.full, self.full_horizon = cfg, full, horizon
        self.samples, self.horizon = full, horizon
        self.step = max(1, full // 20)
        self.per_unit: float | None = None  # running seconds per sample-step
        self._room = 0  # iterations in a row that had room for more

    @property
    def period(self) -> float:
        """The budget of an iteration, s."""
        return 1.0 / self.cfg.rate

    def observe(self, seconds: float) -> Change | None:
        """An iteration of the current samples and horizon took ``seconds``: the change when
        one is due (:attr:`samples` or :attr:`horizon` is then the new one), else None."""
        if not (math.isfinite(seconds) and seconds > 0):
            return None
        rate = seconds / (self.samples * self.horizon)
        old = rate if self.per_unit is None else self.per_unit
        self.per_unit = (1 - SMOOTHING) * old + SMOOTHING * rate
        fits = HEADROOM * self.period / self.per_unit  # sample-steps
        over = f"iteration {seconds * 1e3:.0f} ms over the budget of {self.period * 1e3:.0f} ms"
        if seconds > self.period:
            self._room = 0
            if self.samples > self.cfg.min_samples:
                fit = self._quantise(fits / self.horizon)
                after = max(self.cfg.min_samples, min(self.samples - self.step, fit))
                return self._set("samples", after, over)
            if self.horizon > self.cfg.min_horizon:
                fit = int(fits // self.samples)
                after = max(self.cfg.min_horizon, min(self.horizon - 1, fit))
                return self._set("horizon", after, over + " at the fewest samples")
            return None
        room = f"{self.cfg.patience} iterations with room in the budget"
        if self.horizon < self.full_horizon and fits >= self.samples * (self.horizon + 1):
            return self._grow("horizon", self.horizon + 1, room)
        if self.samples < self.full and fits >= (self.samples + self.step) * self.horizon:
            return self._grow("samples", min(self.full, self.samples + self.step), room)
        self._room = 0
        return None

    def _grow(self, what: str, after: int, reason: str) -> Change | None:
        self._room += 1
        if self._room < self.cfg.patience:
            return None
        self._room = 0
        return self._set(what, after, reason)

    def _quantise(self, n: float) -> int:
        return int(n // self.step) * self.step

    def _set(self, what: str, after: int, reason: str) -> Change | None:
        before = getattr(self, what)
        if after == before:
            return None
        setattr(self, what, after)
        return Change(what, before, after, reason)
