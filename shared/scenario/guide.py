"""The scenario's ``guide:`` key: a global path for the robot or for an object it moves, which
the planner keeps up to date and its cost terms follow (planner_client/guide.py; docs/scenarios.md,
"A global guide"). Parsed and checked here, once, at load."""

from __future__ import annotations

import math
from dataclasses import dataclass

from shared.config import Section, non_negative, one_of, positive, string_list

# the most cells of the guide's grid: its A* (planner_client/global_path.py) runs in Python,
# beside the planner (about 1 s across a 500 x 500 grid with a wall to go round, on 2 cores of
# an AMD EPYC); resolution: 0.0001 over a 10 m arena asked for 32.7 GiB
GUIDE_MAX_CELLS = 250_000
# room the grid keeps around what it covers, each side (planner_client.global_path.Grid.around)
GRID_ROOM = 1.0

# the planners a guide may use (planner_client.guide.METHODS implements each)
GUIDE_METHODS = ("astar",)
ROOM_MODES = ("none", "push", "pull", "any")


@dataclass(frozen=True)
class GuideConfig:
    """``guide:``: a path for body ``for_`` (``robot``, a body of the robot, e.g. a mobile base,
    or a free object) to frame ``goal``, planned by ``method`` on a grid of ``resolution`` m
    around the obstacles, each grown by the body's footprint ``radius`` (None: from its geoms)
    plus ``inflate``. For an object, ``room`` asks for room for the robot beside it at each step
    (``push``: behind, ``pull``: ahead or at its side, ``any``: either), touching it and ``gap``
    m clear of the obstacles. The sub-goal ``site:guide`` sits ``lookahead`` m along the path
    beyond the body; the path is planned again when an obstacle moves more than ``replan_move``
    m or the body is more than ``replan_distance`` m off it."""

    for_: str
    goal: str
    method: str = "astar"
    resolution: float = 0.1
    inflate: float = 0.05
    radius: float | None = None
    room: str = "none"
    gap: float = 0.02
    lookahead: float = 0.6
    replan_distance: float = 0.5
    replan_move: float = 0.05
    obstacles: tuple[str, ...] | None = None  # None: walls, obstacles and other free objects


def parse_guide(s: Section, objects: dict[str, bool]) -> GuideConfig:
    """``objects``: the world's objects by name, True for the free ones (any other name is the
    robot's body, checked against the planner's model when it is built)."""
    for_ = s.req("for", str, "robot, a body of the robot or a free object's name")
    if for_ in objects and not objects[for_]:
        free = [n for n, f in objects.items() if f]
        expected = ", ".join(["robot", *free]) if free else "robot (the world has no free object)"
        raise s.error("for", "not the robot or a free object", for_, expected)
    cfg = GuideConfig(
        for_=for_,
        goal=s.req("goal", str, "a frame name"),
        method=s.opt("method", "astar", one_of(GUIDE_METHODS)),
        resolution=s.opt("resolution", 0.1, positive, "metres > 0"),
        inflate=s.opt("inflate", 0.05, non_negative, "metres >= 0"),
        radius=s.opt("radius", None, positive, "metres > 0"),
        room=s.opt("room", "none", one_of(ROOM_MODES)),
        gap=s.opt("gap", 0.02, non_negative, "metres >= 0"),
        lookahead=s.opt("lookahead", 0.6, non_negative, "metres >= 0"),
        replan_distance=s.opt("replan_distance", 0.5, positive, "metres > 0"),
        replan_move=s.opt("replan_move", 0.05, positive, "metres > 0"),
        obstacles=s.opt("obstacles", None, string_list, "a list of body names"),
    )
    if cfg.room != "none" and not objects.get(for_, False):
        raise s.error("room", "is for an object the robot moves", cfg.room, "none for the robot")
    if cfg.resolution > 1.0:
        raise s.error(
            "resolution", "too coarse for a path between obstacles", cfg.resolution, "metres <= 1"
        )
    s.done()
    return cfg


def grid_cells(resolution: float, span: tuple[float, float]) -> int:
    """Cells of a guide's grid of ``resolution`` m over a world ``span`` m wide and deep (the
    arena and the objects), with :data:`GRID_ROOM` around it."""
    nx, ny = (math.ceil((s + 2 * GRID_ROOM) / resolution) + 1 for s in span)
    return nx * ny


def check_grid(s: Section, cfg: GuideConfig, span: tuple[float, float]) -> None:
    """The guide's grid over the world ``span`` holds at most :data:`GUIDE_MAX_CELLS` cells."""
    cells = grid_cells(cfg.resolution, span)
    if cells <= GUIDE_MAX_CELLS:
        return
    finest = (max(span) + 2 * GRID_ROOM) / (math.sqrt(GUIDE_MAX_CELLS) - 1)
    raise s.error(
        "resolution",
        f"a grid of {cells:,} cells over the world's {span[0]:g} x {span[1]:g} m",
        cfg.resolution,
        f"at most {GUIDE_MAX_CELLS:,} cells: metres >= {finest:.3f}",
    )
