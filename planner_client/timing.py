"""Keeping time against a world that does not wait: when the next plan will take effect, what
the state will be by then, and how far the warm start must move.

A real-time world keeps playing the previous plan while the planner computes. So the planner
plans not from the state it received (time ``t_s``) but from the state the world will be in when
the new plan arrives, ``t_eff = t_s + lead``: it predicts it by stepping its own model over the
lead under the plan being played, and dates its plan's first knot ``t_eff``. The lead is learnt
from ``state.lag`` (world seconds between publishing a state and the arrival of the command that
answered it: planning plus transport, both ways). In lock-step the world waits and the lag is 0,
unless the world publishes its states late: then it is their state delay, which a planner
estimating its delays (``planner.delays.measure``) plans ahead by.

Delays no message shows (``planner.delays``, declared: docs/faults.md) come on top: a state
published ``state_ms`` after its measurement, and actuators that act ``actuation_ms`` after a
control reaches the world. The plan is dated when it reaches the world: ``t_s + lead`` in real
time, where the lag is measured from the state's measurement time and so holds the state delay,
``t_s + state`` in lock-step. It is planned from the state at which its first knot acts,
``actuation`` later, reached under the controls the actuators are still working through (those
the world played ``actuation`` earlier).
"""

from __future__ import annotations

import math
from collections import deque
from contextlib import contextmanager

import mujoco
import numpy as np

from planner_client.team import TeamRollouts
from shared.timed_plan import TIME_EPS, TimedPlan


class LeadEstimate:
    """The lead to plan ahead by: the largest of the last ``window`` lags, rounded up to whole
    world steps. The largest, because a plan that arrives before its time waits harmlessly
    (the previous one plays on, as predicted), while one that arrives late loses its first knots
    and starts from a state it did not predict."""

    def __init__(self, world_dt: float, window: int = 10, max_steps: int | None = None):
        self.world_dt = world_dt
        self.max_steps = max_steps  # a lead beyond the plan's span predicts nothing it plays
        self._lags: deque[float] = deque(maxlen=window)

    def observe(self, lag: float) -> None:
        if lag > 0:
            self._lags.append(lag)

    def steps(self) -> int:
        """World steps to predict ahead (0 until a lag was observed)."""
        if not self._lags:
            return 0
        steps = max(self._lags) / self.world_dt - 1e-6
        if self.max_steps is not None and steps > self.max_steps:
            return self.max_steps
        return math.ceil(steps)


@contextmanager
def _timestep(model: mujoco.MjModel, dt: float):
    """``model`` stepping at ``dt`` (the world's) inside the block, its own timestep after."""
    saved = model.opt.timestep
    model.opt.timestep = dt
    try:
        yield
    finally:
        model.opt.timestep = saved


def predict(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    plans: list[TimedPlan],
    safe: np.ndarray,
    world_dt: float,
    steps: int,
    actuation_delay: float = 0.0,
    team: TeamRollouts | None = None,
) -> None:
    """Steps ``data`` (the mirrored state) ``steps`` world steps ahead, in place, under the
    controls the world will apply meanwhile (``plans``: the last ones sent, oldest first), each
    acting ``actuation_delay`` seconds after the world plays it; at the world's timestep even
    when the planning model's is coarser, so that the predicted state is on the world's time
    grid. A team's planner: the other robots go as their plans say (``team``)."""
    if steps <= 0:
        return
    controls = played(model, plans, safe, float(data.time), world_dt, steps, actuation_delay, team)
    step_through(model, data, controls, world_dt)


def played(
    model: mujoco.MjModel,
    plans: list[TimedPlan],
    safe: np.ndarray,
    start: float,
    world_dt: float,
    steps: int,
    actuation_delay: float = 0.0,
    team: TeamRollouts | None = None,
) -> np.ndarray:
    """``[steps, nu]``: the controls the world applies over ``steps`` world steps from time
    ``start`` (:func:`predict`'s), clipped to the actuators' ranges. The times add up step by
    step as ``mj_step`` adds them, so that each control is the one :func:`predict` would read."""
    lo, hi = model.actuator_ctrlrange.T
    limited = model.actuator_ctrllimited.astype(bool)
    out = np.empty((steps, model.nu))
    t = start
    for k in range(steps):
        u = playing(plans, t - actuation_delay)
        u = safe if u is None else u
        u = u if team is None else team.widen_one(u, t)
        out[k] = np.where(limited, np.clip(u, lo, hi), u)
        t += world_dt
    return out


def playing(plans: list[TimedPlan], t: float) -> np.ndarray | None:
    """What a world's :class:`server.plan_player.PlanPlayer` that received ``plans`` in order
    (``t0`` not decreasing) applies at ``t``, without playing them: the newest that has started;
    None (the safe control) when none has, or that one has run out. The planner uses it to
    predict the world."""
    plan = next((p for p in reversed(plans) if t + TIME_EPS >= p.t0), None)
    return None if plan is None else plan.at(t)


def step_through(
    model: mujoco.MjModel, data: mujoco.MjData, controls: np.ndarray, world_dt: float
) -> None:
    """Steps ``data`` in place under ``controls [steps, nu]``, one world step each."""
    with _timestep(model, world_dt):
        for u in controls:
            data.ctrl[:] = u
            mujoco.mj_step(model, data)


def steps_between(t_from: float, t_to: float, dt: float) -> float:
    """``(t_to - t_from) / dt`` control steps, snapped to a whole number within 1e-6 so that
    lock-step iterations shift by exactly one step (float times differ in the last bits)."""
    steps = (t_to - t_from) / dt
    nearest = round(steps)
    return float(nearest) if abs(steps - nearest) < 1e-6 else steps
