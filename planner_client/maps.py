"""The planner's map of a scenario with lidars (issue 56): a 2-D occupancy grid over the arena,
fused from the lidars' scans, composed with the obstacles the planner's model declares (walls
and fixed objects), and published to ``problem.field_source``, where the guide and the
``perceived_clearance`` term read it. ``planner.map`` sets its ``resolution`` (m) and ``rate``
(fields a second in real time); shared/scenario only carries the mapping, read here.

Depth cameras are simulated and their scans travel with the states, but the planner does not
fuse them: a 3-D map of an arm's workspace is not planned with yet.
"""

from __future__ import annotations

import functools
import logging

import mujoco

from planner_client.guide import ObstacleGeoms
from planner_client.perception.field import DistanceField
from planner_client.perception.grid2d import OccupancyGrid2D
from planner_client.perception.occupancy import MapConfig
from planner_client.perception.sdf import known_field
from planner_client.perception.updater import MapUpdater
from planner_client.problem import PlanningProblem, obstacle_names
from shared.config import Section, positive
from shared.scenario import Scenario

log = logging.getLogger("m3p2i.planner")

_MARGIN = 0.5  # m of map beyond the arena's walls: their faces and a little behind lie inside


def map_config(scenario: Scenario) -> MapConfig:
    """``planner.map``'s keys as a :class:`MapConfig` (defaults: MapConfig's)."""
    s = Section(scenario.planner.map, scenario.source, "planner.map")
    cfg = MapConfig(
        resolution=s.opt("resolution", MapConfig.resolution, positive, "metres > 0"),
        rate_hz=s.opt("rate", MapConfig.rate_hz, positive, "fields a second > 0"),
    )
    s.done()
    return cfg


def lidar_names(scenario: Scenario) -> list[str]:
    """The scenario's lidars, which the 2-D map reads (its depth cameras are noted, once)."""
    if any(s.kind == "depth" for s in scenario.sensors):
        _note_depth(scenario.source)
    return [s.name for s in scenario.sensors if s.kind == "lidar"]


@functools.cache
def _note_depth(source: str) -> None:
    log.info("%s: depth cameras are not fused: the planner plans with 2-D lidar maps only", source)


def known_obstacles(problem: PlanningProblem, grid: OccupancyGrid2D) -> DistanceField:
    """The declared obstacles' signed distance on ``grid``: the walls and the fixed objects of
    the planner's model at their start poses (free objects move, and the rollouts feel them
    in the model already)."""
    scenario = problem.scenario
    free = {o.name for o in scenario.world.objects if not o.fixed}
    names = [n for n in obstacle_names(scenario) if n not in free]
    bodies = [problem.resolve(n).id for n in names]
    data = mujoco.MjData(problem.model)
    mujoco.mj_kinematics(problem.model, data)
    geoms = ObstacleGeoms.of(problem.model, data, bodies)
    return known_field(geoms.shapes(geoms.poses(data)), grid.spec)


def build_map(problem: PlanningProblem, threaded: bool) -> MapUpdater | None:
    """The map of ``problem``'s lidars, connected to ``problem.field_source``; None (and the
    slot left empty) without a lidar. ``threaded``: real time (module
    :mod:`planner_client.perception.updater`)."""
    scenario = problem.scenario
    lidars = lidar_names(scenario)
    if not lidars:
        return None
    world = scenario.world
    # without walls: a square round the origin as wide as everything declared, wherever it lies
    half = world.arena.half_size if world.arena is not None else max(world.span())
    grid = OccupancyGrid2D.arena(half, _MARGIN, map_config(scenario))
    updater = MapUpdater(
        grid, known=known_obstacles(problem, grid), sensors=lidars, threaded=threaded
    )
    problem.field_source.connect(updater)
    return updater
