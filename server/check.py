"""What the world checks before it starts: the scenario file, and every name in it that only
the compiled model can confirm (success-test frames, disturbance conditions, metrics frames).

Every error of the file is collected, so an author fixes them in one round; ``m3p2i-server
--check`` prints them, and ``m3p2i check`` / ``m3p2i run`` merge them with the planner's.
"""

from __future__ import annotations

import os

from shared.config import ConfigError, ErrorLog
from shared.evaluation.metrics import MetricsEvaluator
from shared.frames import FrameResolver
from shared.predicates import check_frames
from shared.robots import get_robot
from shared.scenario import MoveConfig, Scenario, read_scenario
from shared.scene import compile_model


def model_errors(scenario: Scenario) -> list[ConfigError]:
    """Errors of the names the world resolves against its compiled model."""
    errors = ErrorLog()
    try:
        model = compile_model(scenario)
    except ValueError as exc:      # e.g. robot.qpos longer than the model's
        return [ConfigError(scenario.source, "", str(exc))]
    resolve = FrameResolver(model, get_robot(scenario.robot.model).frame)
    for i, pred in enumerate(scenario.episode.success):
        errors.call(check_frames, pred, resolve, scenario.source, f"episode.success[{i}]")
    for i, d in enumerate(scenario.world.disturbances):
        if isinstance(d, MoveConfig) and d.when is not None:
            errors.call(check_frames, d.when, resolve, scenario.source,
                        f"world.disturbances[{i}].move.when")
    errors.call(MetricsEvaluator, scenario, model)
    return errors.errors


def scenario_errors(name_or_path: str | os.PathLike) -> list[ConfigError]:
    """Every error of a scenario file the world would meet: loading, then the model checks."""
    reading = read_scenario(name_or_path)
    errors = list(reading.errors)
    if reading.model_ok:
        errors += model_errors(reading.scenario)
    return errors
