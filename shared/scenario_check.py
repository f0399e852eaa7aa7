"""Checking a scenario file before a process starts: every error at once.

Loading collects the file's own faults (:func:`shared.scenario.read_scenario`); then each
process checks what it resolves against the compiled model (``server.world_check``,
``planner_client.planner_check``), through :func:`scenario_errors`. When the robot and world
were not read cleanly, the file's model cannot be built, yet the names the file uses (frames of
cost terms, observers, the success test) are still checked: against the robot's bodies and
sites and the objects the world declares, so a misspelt frame is reported beside a type error.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable

import mujoco

from shared.config import ConfigError, ErrorLog
from shared.frames import FrameResolver
from shared.scenario import Scenario, read_scenario
from shared.scene import build_spec, compile_model

# (scenario, its compiled model, a resolver of its frame names, where errors go)
ModelChecks = Callable[[Scenario, mujoco.MjModel, FrameResolver, ErrorLog], None]


def scenario_errors(
    name_or_path: str | os.PathLike, model_checks: ModelChecks, name_checks: ModelChecks
) -> list[ConfigError]:
    """Every error of a scenario file: loading, then ``model_checks`` on its compiled model;
    when the file's model cannot be built (a faulty robot or world), ``name_checks`` (the
    part of ``model_checks`` that only looks names up) on the model of the robot and the
    names the world declares."""
    reading = read_scenario(name_or_path)
    errors = ErrorLog()
    errors.errors = list(reading.errors)
    scenario = reading.scenario
    if scenario is None:
        return errors.errors
    if not reading.model_ok:
        # the stand-in world (shared.scenario._declared_world) has placeholder objects: the
        # robot's start (robot.qpos) is not this model's to check
        scenario = dataclasses.replace(
            scenario, robot=dataclasses.replace(scenario.robot, qpos=None)
        )
        try:
            model = build_spec(scenario).compile()
        except ValueError:  # e.g. a declared name that clashes with the robot's
            return errors.errors
        name_checks(scenario, model, _resolver(scenario, model), errors)
        return errors.errors
    try:
        model = compile_model(scenario)
    except ValueError as exc:  # e.g. robot.qpos longer than the model's
        return errors.errors + [ConfigError(scenario.source, "robot.qpos", str(exc))]
    model_checks(scenario, model, _resolver(scenario, model), errors)
    return errors.errors


def _resolver(scenario: Scenario, model: mujoco.MjModel) -> FrameResolver:
    return FrameResolver(model, scenario.robot.spec.frame)
