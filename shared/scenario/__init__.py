"""Scenario files: one YAML per scenario (found as :mod:`shared.config_files` says), parsed into
typed dataclasses and validated once, at load. Both processes load the same file; its hash is
checked in the handshake so that they can never silently plan for different worlds.

The schema, key by key, is documented in ``docs/scenarios.md``.

One module per section (``robot``, ``world``, ``sensors``, ``episode``, ``objectives``, ``task``,
``planner`` and its ``model``, ``variants``, ``estimate``, ``mppi``); ``reader`` reads a file
whole. The names
both processes use are re-exported here; the rest are in their section's module."""

from shared.scenario.episode import EpisodeConfig, MetricsConfig
from shared.scenario.model import Attach, PlanningModel
from shared.scenario.objectives import ObjectiveConfig, TermConfig, find_objectives
from shared.scenario.planner import ROLLOUT_BACKENDS, DelayConfig, PlannerConfig, rollout_device
from shared.scenario.reader import (
    SCENARIO_DIR,
    Scenario,
    ScenarioReading,
    find_scenario,
    load_scenario,
    parse_scenario,
    read_scenario,
    scenario_hash,
    with_base,
)
from shared.scenario.robot import RobotConfig
from shared.scenario.task import ObserverConfig
from shared.scenario.tracking import TrackingConfig
from shared.scenario.variants import VARIANT_PARAMS, VariantsConfig
from shared.scenario.world import (
    MoveConfig,
    ObjectConfig,
    PathConfig,
    RandomizeConfig,
    WorldConfig,
)
