"""What the planner checks before it starts: the scenario file, and every name in it that only
the compiled model or the planner's registries can confirm (cost terms and their frames and
actuators, pinned controls, observers' frames, ``planner.mppi`` keys).

Every error of the file is collected, so an author fixes them in one round; ``m3p2i-planner
--check`` prints them, and ``m3p2i check`` / ``m3p2i run`` merge them with the world's.
"""

from __future__ import annotations

import os

from shared.config import ConfigError, ErrorLog
from shared.frames import FrameResolver
from shared.predicates import check_frames
from shared.robots import get_robot
from shared.scenario import Scenario, read_scenario
from shared.scene import compile_model
from planner_client.problem import actuator_names, build_objectives, mppi_config


def model_errors(scenario: Scenario) -> list[ConfigError]:
    """Errors of what the planner resolves against its compiled model and registries."""
    errors = ErrorLog()
    try:
        model = compile_model(scenario)
    except ValueError as exc:      # e.g. robot.qpos longer than the model's
        return [ConfigError(scenario.source, "", str(exc))]
    resolve = FrameResolver(model, get_robot(scenario.robot.model).frame)
    errors.call(build_objectives, scenario, resolve, actuator_names(model))
    errors.call(mppi_config, scenario, model)
    for factor, cfg in scenario.observers.items():
        for _, pred in cfg.rules:
            errors.call(check_frames, pred, resolve, scenario.source, f"observers.{factor}")
    return errors.errors


def scenario_errors(name_or_path: str | os.PathLike) -> list[ConfigError]:
    """Every error of a scenario file the planner would meet: loading, then the model checks."""
    reading = read_scenario(name_or_path)
    errors = list(reading.errors)
    if reading.model_ok:
        errors += model_errors(reading.scenario)
    return errors
