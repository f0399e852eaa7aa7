"""What the planner checks before it starts: the scenario file, and every name in it that only
the compiled model or the planner's registries can confirm (cost terms and their frames and
actuators, pinned controls, observers' frames, ``planner.mppi``'s lengths against the
actuators, ``planner.model``'s bodies), and what each cost term returns.

``m3p2i-planner --check`` prints them all; ``m3p2i check`` / ``m3p2i run`` merge them with the
world's.
"""

from __future__ import annotations

import os

import mujoco

from planner_client.budget import budget_config
from planner_client.guide import GuideState, add_site
from planner_client.maps import map_config
from planner_client.problem import (
    actuator_names,
    apply_planning_model,
    build_objectives,
    build_problem,
    check_terms,
    mppi_config,
    own_actuators,
    planner_scenario,
)
from shared.config import ConfigError, ErrorLog
from shared.frames import FrameResolver
from shared.predicates import check_frames
from shared.scenario import Scenario
from shared.scenario_check import scenario_errors as _scenario_errors
from shared.scene import build_spec, compile_model


def _planner_side(
    scenario: Scenario, model: mujoco.MjModel, resolve: FrameResolver
) -> tuple[Scenario, mujoco.MjModel, FrameResolver]:
    """The scenario, model and names as the planner has them: without the perceived objects
    (a cost term or observer naming one is an error: the planner's model lacks it)."""
    known = planner_scenario(scenario)
    if known is scenario:
        return scenario, model, resolve
    model = build_spec(known).compile()
    return known, model, FrameResolver(model, resolve.robot_frame)


def name_checks(
    scenario: Scenario, model: mujoco.MjModel, resolve: FrameResolver, errors: ErrorLog
) -> None:
    """The names the planner looks up: its objectives' cost terms, frames and actuators, its
    observers' frames (a team's: each robot's planner's)."""
    if scenario.members:
        for view in scenario.members.values():
            name_checks(view, model, FrameResolver(model, view.robot.spec.frame), errors)
        return
    scenario, model, resolve = _planner_side(scenario, model, resolve)
    guide = None
    # site:guide is added to the planner's model, not the world's; a faulty guide: section
    # (its own error already reported) still declares it, for the terms that name it
    if scenario.guide is not None or "guide" in scenario.raw:
        spec = build_spec(scenario)
        add_site(spec)
        resolve = FrameResolver(compile_model(scenario, spec), resolve.robot_frame)
    if scenario.guide is not None:
        guide = GuideState(scenario.guide, scenario)
        errors.call(resolve.checked, scenario.guide.for_, scenario.source, "guide.for")
        errors.call(resolve.checked, scenario.guide.goal, scenario.source, "guide.goal")
    actuators = [actuator_names(model)[i] for i in own_actuators(scenario, model)]
    errors.call(build_objectives, scenario, resolve, actuators, guide)
    for factor, cfg in scenario.observers.items():
        for _, pred in cfg.rules:
            errors.call(check_frames, pred, resolve, scenario.source, f"observers.{factor}")


def model_checks(
    scenario: Scenario, model: mujoco.MjModel, resolve: FrameResolver, errors: ErrorLog
) -> None:
    """What the planner resolves against its compiled model and registries (a team's: each
    robot's planner's)."""
    if scenario.members:
        for view in scenario.members.values():
            model_checks(view, model, FrameResolver(model, view.robot.spec.frame), errors)
        return
    scenario, model, resolve = _planner_side(scenario, model, resolve)
    name_checks(scenario, model, resolve, errors)
    errors.call(mppi_config, scenario, model)
    errors.call(map_config, scenario)  # planner.map's keys are the planner's to read
    errors.call(budget_config, scenario)  # so are planner.budget's
    errors.call(apply_planning_model, build_spec(scenario), scenario.planner.model, scenario.source)
    if not errors.errors:  # the terms are built and the planner's model compiles: run them
        errors.call(value_checks, scenario)
    if scenario.planner.backend == "warp" and not errors.errors:
        errors.call(warp_checks, scenario)


def value_checks(scenario: Scenario) -> None:
    """Each cost term evaluated once on a small batch, as the planner does at start-up
    (:func:`~planner_client.problem.check_terms`): one that raises or returns anything but a
    float64 tensor ``[S, T]`` is an error naming the term, its module and its objective."""
    check_terms(build_problem(scenario))


def warp_checks(scenario: Scenario) -> None:
    """planner.backend: warp: the m3p2i[gpu] extra is installed and MJWarp can roll out the
    planner's model (with the sensors its costs add); compiles no kernels."""
    from planner_client.backends.warp import import_warp
    from planner_client.backends.warp_limits import check_warp

    import_warp(scenario.source)
    check_warp(build_problem(scenario).model, scenario.source)


def scenario_errors(name_or_path: str | os.PathLike) -> list[ConfigError]:
    """Every error of a scenario file the planner would meet."""
    return _scenario_errors(name_or_path, model_checks, name_checks)
