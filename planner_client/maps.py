"""The planner's map of a scenario's range sensors (issue 56), published to
``problem.field_source``, where the guide and the ``perceived_clearance`` term read it:

- a **2-D occupancy grid** over the arena, fused from the lidars' scans (a base's map),
  composed with the obstacles the planner's model declares (walls and fixed objects);
- a **3-D voxel grid** over an arm's workspace, fused from the depth cameras' (and lidars')
  scans, composed with the fixed obstacles of the model that reach into it, each scan
  self-filtered: the robot and the free objects the planner models (a cube on the table, the
  cube in the hand) are cut out of it at the poses of the state it came with
  (:mod:`planner_client.perception.self_filter`), so they never become obstacles.

A scenario with a lidar gets the 2-D map, one with depth cameras and no lidar the 3-D one;
``planner.map.dims`` chooses. ``planner.map`` (shared/scenario only carries the mapping, read
here): ``resolution`` (m), ``rate`` (fields a second in real time), and for a 3-D map ``box``
(``[[x0, y0, z0], [x1, y1, z1]]``, m, world frame; default :func:`default_box`) and ``padding``
(m added to the self-filter's spheres).
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import mujoco
import numpy as np

from planner_client.guide import ObstacleGeoms
from planner_client.perception.field import DistanceField
from planner_client.perception.grid import GridSpec
from planner_client.perception.grid2d import OccupancyGrid2D
from planner_client.perception.occupancy import MapConfig
from planner_client.perception.sdf import Solid, known_field, solid_field
from planner_client.perception.updater import MapUpdater
from planner_client.perception.voxels import VoxelGrid
from planner_client.problem import PlanningProblem, obstacle_names
from planner_client.spheres import derive_spheres, robot_bodies, robot_spheres
from shared.config import ConfigError, Section, non_negative, positive, vector
from shared.scenario import Scenario

log = logging.getLogger("m3p2i.planner")

_MARGIN = 0.5  # m of map beyond the arena's walls: their faces and a little behind lie inside
# m added to the self-filter's spheres: a body moves between a reading and the state it
# travels with (1 cm at 1 m/s over one 10 ms step) and a return lies on its surface, which the
# spheres hold with little to spare at a face
PADDING = 0.03
_OVERLAP = 1e-6  # m: a solid that only touches the box (a table under it) does not reach in

Box = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True)
class MapSettings:
    """``planner.map`` read: the map's ``cfg``, ``dims`` (2: the lidars' plane map, 3: voxels),
    a 3-D map's ``box`` (None: :func:`default_box`) and self-filter ``padding`` (m)."""

    cfg: MapConfig
    dims: int
    box: Box | None = None
    padding: float = PADDING


def map_settings(scenario: Scenario) -> MapSettings:
    """``planner.map``'s keys, checked against the scenario's sensors (a ConfigError naming the
    key): ``dims`` defaults to 2 with a lidar, else 3 with a depth camera."""
    s = Section(scenario.planner.map, scenario.source, "planner.map")
    kinds = {c.kind for c in scenario.sensors}
    dims = s.opt("dims", 2 if "lidar" in kinds or not kinds else 3, _dims, "2 or 3")
    if dims == 2 and s.has("dims") and "lidar" not in kinds:
        raise s.error("dims", "a 2-D map reads lidars: the scenario has none", 2)
    if dims == 3 and s.has("dims") and not kinds:
        raise s.error("dims", "a 3-D map reads depth cameras and lidars: none in sensors", 3)
    for key in ("box", "padding"):
        if dims == 2 and s.has(key):
            raise s.error(key, "a 3-D map's key (planner.map.dims: 3)", s.data[key])
    cfg = MapConfig(
        resolution=s.opt("resolution", MapConfig.resolution, positive, "metres > 0"),
        rate_hz=s.opt("rate", MapConfig.rate_hz, positive, "fields a second > 0"),
    )
    box = s.opt("box", None, _box, "[[x0, y0, z0], [x1, y1, z1]] m with x0 < x1, y0 < y1, z0 < z1")
    padding = s.opt("padding", PADDING, non_negative, "metres >= 0")
    s.done()
    return MapSettings(cfg, dims, box, padding)


def map_config(scenario: Scenario) -> MapConfig:
    """``planner.map``'s keys as a :class:`MapConfig` (defaults: MapConfig's), all of them
    checked (:func:`map_settings`)."""
    return map_settings(scenario).cfg


def map_sensors(scenario: Scenario) -> list[str]:
    """The sensors the scenario's map reads: its lidars for a 2-D map (its depth cameras are
    noted, once), its depth cameras and lidars for a 3-D one; none: no map."""
    if not scenario.sensors:
        return []
    if map_settings(scenario).dims == 3:
        return [s.name for s in scenario.sensors]
    if any(s.kind == "depth" for s in scenario.sensors):
        _note_depth(scenario.source)
    return [s.name for s in scenario.sensors if s.kind == "lidar"]


@functools.cache
def _note_depth(source: str) -> None:
    log.info("%s: depth cameras are not fused into a 2-D map (planner.map.dims: 3 does)", source)


def known_obstacles(problem: PlanningProblem, grid: OccupancyGrid2D) -> DistanceField:
    """The declared obstacles' signed distance on ``grid``: the walls and the fixed objects of
    the planner's model at their start poses (free objects move, and the rollouts feel them
    in the model already)."""
    data = _start(problem)
    geoms = ObstacleGeoms.of(problem.model, data, _fixed_obstacles(problem))
    return known_field(geoms.shapes(geoms.poses(data)), grid.spec)


def known_solids(problem: PlanningProblem, spec: GridSpec) -> DistanceField | None:
    """The signed distance on a 3-D grid of the collision geoms of the fixed obstacles of the
    planner's model (start poses) that reach into its box: a table the box stands on only
    touches it and is left to the model's own contacts (its field would keep the fingers
    from every cube on it). None when no obstacle reaches in."""
    model, data = problem.model, _start(problem)
    lo, hi = spec.bounds
    solids = []
    for body in _fixed_obstacles(problem):
        start, n = model.body_geomadr[body], model.body_geomnum[body]
        for g in range(start, start + n):
            solid = _solid(model, data, g)
            if solid is None:
                continue
            s_lo, s_hi = solid.bounds()
            if np.all(s_lo < hi - _OVERLAP) and np.all(s_hi > lo + _OVERLAP):
                solids.append(solid)
    return solid_field(solids, spec) if solids else None


class SelfFilter:
    """What the planner models, as the spheres a state's scans are cut by: the robot's
    collision spheres (:func:`planner_client.spheres.robot_spheres`) and those of the free
    objects of the planner's model (:func:`planner_client.spheres.derive_spheres`), each
    padded by ``padding`` m. Called with a mirrored scene (an ``MjData`` of the planner's model,
    its kinematics done), it returns their centres and radii ``[n, 4]`` there."""

    def __init__(self, problem: PlanningProblem, padding: float):
        model = problem.model
        spheres = robot_spheres(model, problem.resolve, problem.robot)
        balls = [(model.body(s.body).id, s.pos, s.radius) for s in spheres]
        for name, items in derive_spheres(model, free_bodies(model)).items():
            balls += [(model.body(name).id, (x, y, z), r) for x, y, z, r in items]
        self.bodies = np.array([b for b, _, _ in balls], dtype=int)
        self.local = np.array([p for _, p, _ in balls], dtype=float).reshape(-1, 3)
        self.radii = np.array([r + padding for _, _, r in balls], dtype=float)

    def __call__(self, data: mujoco.MjData) -> np.ndarray:
        rot = data.xmat[self.bodies].reshape(-1, 3, 3)
        centres = data.xpos[self.bodies] + np.einsum("nij,nj->ni", rot, self.local)
        return np.column_stack([centres, self.radii])


def free_bodies(model: mujoco.MjModel) -> list[int]:
    """The bodies of ``model`` that a free joint moves (a scenario's free objects)."""
    free = model.jnt_type == mujoco.mjtJoint.mjJNT_FREE
    return sorted({int(b) for b in model.jnt_bodyid[free]})


def default_box(problem: PlanningProblem, resolution: float) -> Box:
    """A 3-D map's box when ``planner.map.box`` is not given: every point the robot reaches
    from its base's start (the chain of its bodies' offsets and its geoms' extents: a bound, not
    the reachable set), above the top of the fixed obstacle it stands on (a table: the model's,
    not fused, :func:`known_solids`) plus half a cell, so that the returns on that top lie
    outside; without one, above the floor (z = 0)."""
    model, data = problem.model, _start(problem)
    robot = robot_bodies(model, problem.resolve)
    root = robot[0]
    chain = np.zeros(model.nbody)
    for b in robot[1:]:  # parents come first in MuJoCo's body order
        chain[b] = chain[model.body_parentid[b]] + np.linalg.norm(model.body_pos[b])
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in robot]
    reach = max(
        chain[model.geom_bodyid[g]] + np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g]
        for g in geoms
    )
    base = data.xpos[root]
    floor = 0.0
    for body in _fixed_obstacles(problem):
        start, n = model.body_geomadr[body], model.body_geomnum[body]
        for g in range(start, start + n):
            solid = _solid(model, data, g)
            if solid is None or solid.kind == "plane":
                continue
            lo, hi = solid.bounds()
            if np.all(lo[:2] <= base[:2]) and np.all(base[:2] <= hi[:2]) and hi[2] <= base[2]:
                floor = max(floor, float(hi[2]))
    lo = (base[0] - reach, base[1] - reach, floor + resolution / 2)
    hi = (base[0] + reach, base[1] + reach, base[2] + reach)
    return tuple(float(v) for v in lo), tuple(float(v) for v in hi)


def build_map(problem: PlanningProblem, threaded: bool) -> MapUpdater | None:
    """The map of ``problem``'s sensors (module docstring), connected to
    ``problem.field_source``; None (and the slot left empty) without a sensor it reads.
    ``threaded``: real time (module :mod:`planner_client.perception.updater`)."""
    scenario = problem.scenario
    sensors = map_sensors(scenario)
    if not sensors:
        return None
    settings = map_settings(scenario)
    if settings.dims == 3:
        updater = _voxel_map(problem, settings, sensors, threaded)
    else:
        world = scenario.world
        # without walls: a square round the origin as wide as everything declared, wherever
        half = world.arena.half_size if world.arena is not None else max(world.span())
        grid = OccupancyGrid2D.arena(half, _MARGIN, settings.cfg)
        known = known_obstacles(problem, grid)
        updater = MapUpdater(grid, known=known, sensors=sensors, threaded=threaded)
    problem.field_source.connect(updater)
    return updater


def _voxel_map(
    problem: PlanningProblem, settings: MapSettings, sensors: list[str], threaded: bool
) -> MapUpdater:
    cfg = settings.cfg
    lo, hi = settings.box or default_box(problem, cfg.resolution)
    try:
        grid = VoxelGrid(lo, hi, cfg)
    except ValueError as exc:  # too many voxels a side for the resolution
        raise ConfigError(problem.scenario.source, "planner.map.box", str(exc)) from None
    log.info(
        "3-D map: %d x %d x %d voxels of %.3f m over %s to %s",
        *grid.spec.shape[::-1],
        cfg.resolution,
        np.round(lo, 3).tolist(),
        np.round(hi, 3).tolist(),
    )
    return MapUpdater(
        grid,
        known=known_solids(problem, grid.spec),
        sensors=sensors,
        threaded=threaded,
        self_filter=SelfFilter(problem, settings.padding),
    )


def _start(problem: PlanningProblem) -> mujoco.MjData:
    """The planner's model at its start poses, kinematics done."""
    data = mujoco.MjData(problem.model)
    mujoco.mj_kinematics(problem.model, data)
    return data


def _fixed_obstacles(problem: PlanningProblem) -> list[int]:
    """The body ids of the declared obstacles that are not free (walls, fixed objects)."""
    scenario = problem.scenario
    free = {o.name for o in scenario.world.objects if not o.fixed}
    return [problem.resolve(n).id for n in obstacle_names(scenario) if n not in free]


_KINDS = {
    mujoco.mjtGeom.mjGEOM_BOX: "box",
    mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
    mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
    mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder",
    mujoco.mjtGeom.mjGEOM_PLANE: "plane",
}


def _solid(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> Solid | None:
    """Geom ``g`` as a :class:`Solid` where ``data`` has it (any other kind: its bounding
    sphere); None for one that collides with nothing or a plane facing up (a floor)."""
    if not (model.geom_contype[g] or model.geom_conaffinity[g]):
        return None
    rot = data.geom_xmat[g].reshape(3, 3)
    kind = _KINDS.get(int(model.geom_type[g]))
    size = tuple(float(v) for v in model.geom_size[g])
    if kind == "plane" and rot[2, 2] > 0.7:
        return None
    if kind is None:
        kind, size = "sphere", (float(model.geom_rbound[g]), 0.0, 0.0)
    pos = tuple(float(v) for v in data.geom_xpos[g])
    return Solid(kind, size, pos, tuple(tuple(float(v) for v in row) for row in rot))


def _dims(value: object) -> int:
    if isinstance(value, bool) or value not in (2, 3):
        raise ValueError("must be 2 or 3")
    return int(value)


def _box(value: object) -> Box:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError("needs two corners")
    lo, hi = (vector(3)(v) for v in value)
    if not all(a < b for a, b in zip(lo, hi)):
        raise ValueError("the first corner must be below the second on every axis")
    return lo, hi
