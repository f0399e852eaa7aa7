"""What a planner's rollout costs, part by part: its bare ``mujoco.rollout`` with parts of the
physics switched off, and the planner rates those times allow (what is timed:
:mod:`scripts.measure.rollout_parts`).

    python scripts/rollout_floor.py -s navigation -s push_pull_fast --samples 400 --horizon 15
"""

from __future__ import annotations

import os

import typer
from rich.console import Console

from m3p2i.cli_support import scenarios_or_exit
from measure.rollout_parts import floor_table

app = typer.Typer(add_completion=False)


@app.command()
def main(
    scenario: list[str] = typer.Option(
        ["navigation", "push_pull", "push_pull_fast"], "--scenario", "-s", help="Scenarios to time."
    ),
    samples: int = typer.Option(400, min=1, help="Rollouts per call (all modes together)."),
    horizon: int = typer.Option(
        15, min=1, help="Steps per rollout, each of the scenario's planner.timestep."
    ),
    threads: int = typer.Option(0, min=0, help="Rollout threads (0: one per core)."),
    rounds: int = typer.Option(20, min=1, help="Timed rounds (each times every variant once)."),
) -> None:
    """Time the bare rollout of each scenario's planner model, as planned and with its
    sensors, contacts or constraints switched off."""
    nthread = threads or os.cpu_count() or 1
    scenarios_or_exit(scenario)
    Console().print(floor_table(scenario, samples, horizon, nthread, rounds))


if __name__ == "__main__":
    app()
