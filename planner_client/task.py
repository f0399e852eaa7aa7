"""The task layer: which objectives the motion planner optimises, decided each tick.

A scenario either lists its modes directly (``modes:``: fixed for the whole episode) or, with a
``task:`` action template, has them chosen by active inference (paper Alg. 1-2): the alternative
actions become the modes of M3P2I.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np


@dataclass(frozen=True)
class TaskDecision:
    action: str                          # the task-level action being executed (for logs)
    modes: tuple[str, ...]               # objectives handed to M3P2I, one mode each
    alternatives: tuple[str, ...] = ()   # all admissible actions the task planner found
    override: np.ndarray | None = None   # a control to send instead of the planner's (idle)


class TaskLayer(Protocol):
    def decide(self, data: mujoco.MjData, extras: dict[str, float], time: float) -> TaskDecision:
        """Choose the modes for this tick from the mirrored world state."""


class FixedModes:
    """The scenario's ``modes:`` list, every tick."""

    def __init__(self, modes: tuple[str, ...]):
        self.decision = TaskDecision(action="+".join(modes), modes=tuple(modes),
                                     alternatives=tuple(modes))

    def decide(self, data, extras, time) -> TaskDecision:
        return self.decision
