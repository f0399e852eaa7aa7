"""What the measuring scripts check of their options before they measure anything."""

from __future__ import annotations

import argparse

import typer

from shared.config import ConfigError
from shared.scenario import Scenario, load_scenario


def scenarios_or_usage_error(
    names: list[str], flag: str = "--scenario", teams: bool = True
) -> list[Scenario]:
    """Each scenario of ``names`` loaded, or a usage error (exit 2) naming the first that is
    not a sound scenario file or name (``teams``: whether a scenario of several robots is
    measured too)."""
    scenarios = []
    for name in names:
        try:
            sc = load_scenario(name)
        except ConfigError as exc:
            raise typer.BadParameter(str(exc), param_hint=flag) from None
        if sc.team and not teams:
            raise typer.BadParameter(
                f"{name}: a scenario of {len(sc.team)} robots starts a planner per robot; "
                "this measures one (expected a scenario of one robot)",
                param_hint=flag,
            )
        scenarios.append(sc)
    return scenarios


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value
