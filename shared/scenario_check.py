"""Checking a scenario file before a process starts: every error at once.

Loading collects the file's own faults (:func:`shared.scenario.read_scenario`); then, when the
robot and world were read cleanly, each process checks what it resolves against the compiled
model (``server.world_check``, ``planner_client.planner_check``), through :func:`scenario_errors`.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import mujoco

from shared.config import ConfigError, ErrorLog
from shared.frames import FrameResolver
from shared.robots import get_robot
from shared.scenario import Scenario, read_scenario
from shared.scene import compile_model

# (scenario, its compiled model, a resolver of its frame names, where errors go)
ModelChecks = Callable[[Scenario, mujoco.MjModel, FrameResolver, ErrorLog], None]


def scenario_errors(name_or_path: str | os.PathLike, model_checks: ModelChecks) -> list[ConfigError]:
    """Every error of a scenario file: loading, then ``model_checks`` on its compiled model."""
    reading = read_scenario(name_or_path)
    errors = ErrorLog()
    errors.errors = list(reading.errors)
    if not reading.model_ok:
        return errors.errors
    scenario = reading.scenario
    try:
        model = compile_model(scenario)
    except ValueError as exc:      # e.g. robot.qpos longer than the model's
        return errors.errors + [ConfigError(scenario.source, "robot.qpos", str(exc))]
    model_checks(scenario, model, FrameResolver(model, get_robot(scenario.robot.model).frame),
                 errors)
    return errors.errors
