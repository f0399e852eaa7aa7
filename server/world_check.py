"""What the world checks before it starts: the scenario file, and every name in it that only
the compiled model can confirm (success-test frames, disturbance conditions, metrics frames,
the sensors' frames).

``m3p2i-server --check`` prints them all; ``m3p2i check`` / ``m3p2i run`` merge them with the
planner's.
"""

from __future__ import annotations

import os

import mujoco

from server.evaluation.metrics import MetricsEvaluator
from shared.config import ConfigError, ErrorLog
from shared.frames import Frame, FrameResolver
from shared.predicates import check_frames
from shared.scenario import MoveConfig, Scenario
from shared.scenario.sensors import WORLD_FRAME
from shared.scenario_check import scenario_errors as _scenario_errors


def model_checks(
    scenario: Scenario, model: mujoco.MjModel, resolve: FrameResolver, errors: ErrorLog
) -> None:
    """The names the world resolves against its compiled model: the frames of its success test
    (no free perceived object) and disturbances, the frames and bodies of its metrics, its
    sensors' frames. Only names: the same checks serve on the stand-in model of a file whose
    own model cannot be built."""
    known = _Known(resolve, {o.name for o in scenario.world.objects if o.perceived and not o.fixed})
    for i, pred in enumerate(scenario.episode.success):
        errors.call(check_frames, pred, known, scenario.source, f"episode.success[{i}]")
    for i, d in enumerate(scenario.world.disturbances):
        if isinstance(d, MoveConfig) and d.when is not None:
            errors.call(
                check_frames, d.when, resolve, scenario.source, f"world.disturbances[{i}].move.when"
            )
    for i, sensor in enumerate(scenario.sensors):
        if sensor.frame != WORLD_FRAME:
            errors.call(resolve.checked, sensor.frame, scenario.source, f"sensors[{i}].frame")
    errors.call(MetricsEvaluator, scenario, model)


class _Known(FrameResolver):
    """The world's frames but its free perceived objects: the success test may not name one,
    since the planner that must bring it about never learns where it is (only scans show it)."""

    def __init__(self, resolve: FrameResolver, hidden: set[str]):
        super().__init__(resolve.model, resolve.robot_frame)
        self.hidden = hidden

    def checked(self, name: str, source: str, key: str) -> Frame:
        if name in self.hidden:
            raise ConfigError(
                source,
                key,
                "a free perceived object: the planner's model lacks it, so no plan can succeed "
                "on it",
                name,
                "an object with perceived: false",
            )
        return super().checked(name, source, key)


def scenario_errors(name_or_path: str | os.PathLike) -> list[ConfigError]:
    """Every error of a scenario file the world would meet."""
    return _scenario_errors(name_or_path, model_checks, name_checks=model_checks)
