"""Symbolic observers (paper Eqs. 13, 23-26; thesis Eqs. 4.2-4.3): continuous state -> the
observed discrete state of each task factor, from the predicates named in the scenario YAML."""

from __future__ import annotations

import mujoco

from shared.frames import FrameResolver
from shared.predicates import BoundPredicate, WorldView
from shared.scenario import ObserverConfig


class SymbolicObserver:
    """Evaluates every factor's rules on the mirrored state; first rule that holds wins."""

    def __init__(self, observers: dict[str, ObserverConfig], resolve: FrameResolver):
        self.rules: dict[str, tuple[list[tuple[str, BoundPredicate]], str]] = {
            factor: ([(state, pred.bind(resolve)) for state, pred in cfg.rules], cfg.default)
            for factor, cfg in observers.items()
        }

    def __call__(self, data: mujoco.MjData, extras: dict[str, float]) -> dict[str, str]:
        view = WorldView(data, extras)
        out = {}
        for factor, (rules, default) in self.rules.items():
            out[factor] = next((state for state, pred in rules if pred(view)), default)
        return out
