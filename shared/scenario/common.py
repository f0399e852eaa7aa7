"""Checks several sections share: a step in seconds, a weight, a count."""

from __future__ import annotations

from typing import Any

from shared.config import number

STEP_SECONDS = "seconds in [1e-06, 10]"


def step_seconds(value: Any) -> float:
    """A world's or a planning step: a microsecond to ten seconds (beyond, no simulation; a
    subnormal one made every count of steps overflow)."""
    v = number(value)
    if not 1e-6 <= v <= 10.0:
        raise ValueError("must be between a microsecond and 10 s")
    return v


def unit_weight(value: Any) -> float:
    """A weight of a filter or a forgetting factor: in (0, 1]."""
    v = number(value)
    if not 0.0 < v <= 1.0:
        raise ValueError("must be in (0, 1]")
    return v


def count_of(value: Any) -> int:
    """A count: an integer >= 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError("must be an integer >= 0")
    return value
