"""The task layer: which objectives the motion planner optimises, decided each tick.

A scenario either lists its modes directly (``modes:``: fixed for the whole episode) or, with a
``task:`` action template, has them chosen by active inference (paper Alg. 1-2): the alternative
actions become the modes of M3P2I.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np

from planner_client.aip import ActiveInferencePlanner
from planner_client.observers import SymbolicObserver

log = logging.getLogger("m3p2i.planner")


@dataclass(frozen=True)
class TaskDecision:
    action: str  # the task-level action being executed (for logs)
    modes: tuple[str, ...]  # objectives handed to M3P2I, one mode each
    alternatives: tuple[str, ...] = ()  # all admissible actions the task planner found
    stop: bool = False  # send the robot's safe stop instead of the planner's command


class TaskLayer(Protocol):
    """What the controller reads of a task layer: each tick's decision, and the factors'
    observed states it was made from (the attachments follow them: ``planner.model.attach``)."""

    last_observation: dict[str, str]  # factor -> observed state; {} without a task

    def decide(self, data: mujoco.MjData, extras: dict[str, float], time: float) -> TaskDecision:
        """Choose the modes for this tick from the mirrored world state."""


class FixedModes:
    """The scenario's ``modes:`` list, every tick."""

    def __init__(self, modes: tuple[str, ...]):
        self.last_observation: dict[str, str] = {}
        self.decision = TaskDecision(
            action="+".join(modes), modes=tuple(modes), alternatives=tuple(modes)
        )

    def decide(self, data, extras, time) -> TaskDecision:
        return self.decision


class ConfirmedObservation:
    """Each factor's observed state, changed only once a new state has been observed without a
    break for ``confirm[factor]`` seconds (``"*"``: every other factor; 0 or absent: at once),
    or, when ``confirm[factor]`` maps states to seconds, for the time of the state it changes to:
    ``{reachable: {not_reachable: 0.3}}`` takes "reachable" at once and lets it go only after
    0.3 s without it (hysteresis, for an observer at its threshold under noisy poses).

    An observer at its threshold with noisy poses flips between two states from one tick to the
    next; acted on, every flip would switch the action. A real change (a cube taken from the
    hand) persists, and is acted on after ``confirm`` seconds (plus up to one AIP period, the
    rate the observers are read at)."""

    def __init__(self, confirm: dict[str, float | dict[str, float]]):
        self.confirm = confirm
        self.state: dict[str, str] = {}
        self._candidate: dict[str, tuple[str, float]] = {}  # factor -> (new state, seen since)

    def __call__(self, observed: dict[str, str], time: float) -> dict[str, str]:
        for factor, value in observed.items():
            hold = self.confirm.get(factor, self.confirm.get("*", 0.0))
            if isinstance(hold, dict):  # per state: how long a change *to* it must last
                hold = hold.get(value, 0.0)
            current = self.state.get(factor)
            if current is None or current == value or hold <= 0:
                self.state[factor] = value
                self._candidate.pop(factor, None)
                continue
            candidate = self._candidate.get(factor)
            if candidate is None or candidate[0] != value:
                self._candidate[factor] = candidate = (value, time)
            if time - candidate[1] >= hold - 1e-9:
                self.state[factor] = value
                del self._candidate[factor]
        return dict(self.state)


class ActiveInferenceTask:
    """Observers -> active inference -> alternatives -> objectives (paper Alg. 1, lines 5-9).

    The AIP ticks every ``period`` seconds of simulated time (slower than the motion planner);
    between ticks the last decision stands. Observations reach it through
    :class:`ConfirmedObservation` (``planner.confirm``). Each admissible alternative action
    becomes one M3P2I mode through the plan interface (action -> objective). On success or
    failure the decision says ``stop``: the loop holds the robot with its safe stop; so does a
    team robot's ``wait`` (its action needs another robot's factor first).
    """

    def __init__(
        self,
        aip: ActiveInferencePlanner,
        observer: SymbolicObserver,
        action_objectives: dict[str, str],
        period: float,
        confirm: dict[str, float | dict[str, float]] | None = None,
    ):
        self.aip, self.observer = aip, observer
        self.action_objectives = action_objectives
        self.period = period
        self.confirmed = ConfirmedObservation(confirm or {})
        self._next = -np.inf
        self.decision: TaskDecision | None = None
        self.last_observation: dict[str, str] = {}

    def decide(self, data, extras, time) -> TaskDecision:
        if self.decision is not None and time < self._next:
            return self.decision
        self._next = time + self.period
        self.last_observation = self.confirmed(self.observer(data, extras), time)
        d = self.aip.step(self.last_observation)
        previous = self.decision
        if d.status == "running":
            modes = tuple(dict.fromkeys(self.action_objectives[a] for a in d.alternatives))
            self.decision = TaskDecision(d.action, modes, d.alternatives)
        else:
            keep = previous.modes if previous else ()
            action = {"success": "idle", "waiting": "wait"}.get(d.status, "failure")
            if previous is None or previous.action != action:
                if d.status == "failure":
                    log.error("task planner failed: %s", d.reason)
                elif d.status == "waiting":  # a team's robot: until the others' factors change
                    log.info("%s", d.reason)
            self.decision = TaskDecision(
                action,
                keep or (next(iter(self.action_objectives.values())),),
                (),
                stop=True,
            )
        return self.decision
