"""Global paths in the plane for the guide (planner_client/guide.py): obstacles as 2-D signed
distance functions (and those only a map knows, as its signed distance field), an occupancy grid
of a body's centre, grid A* and the path's simplification.

Pure functions of numpy arrays; nothing here knows MuJoCo. The local planner's horizon is short
(0.75 s): a path over the whole scene, computed here, gives it a sub-goal it can reach without
being trapped (thesis Sec. 5.2's remedy for local minima).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

# the 8 grid moves (di, dj) = (rows: y, columns: x) with their lengths in cells
MOVES = tuple((di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj)
MOVE_LEN = tuple(math.hypot(di, dj) for di, dj in MOVES)


@dataclass(frozen=True)
class Shape:
    """An obstacle's footprint in the plane: ``box`` (``half [2]`` along its axes, turned by
    ``yaw``), ``disk`` (``half[0]`` is the radius) or ``halfplane`` (a wall: free where
    ``(p - centre) · normal > 0``, the normal ``(cos yaw, sin yaw)``)."""

    kind: str
    centre: tuple[float, float]
    half: tuple[float, float] = (0.0, 0.0)
    yaw: float = 0.0

    def extent(self) -> float | None:
        """Radius of a disk around the centre holding the shape; None for a half-plane."""
        return None if self.kind == "halfplane" else math.hypot(*self.half)


@dataclass(frozen=True)
class MapObstacles:
    """Obstacles only a map knows (the planner's perception), as its 2-D signed distance field:
    ``values [H, W]`` (m, negative inside), cell (i, j) centred at ``origin + (j, i) ·
    resolution``; a point off the grid is ``outside`` m from them."""

    values: np.ndarray
    origin: tuple[float, float]
    resolution: float
    outside: float = 1e3

    def distance(self, points: np.ndarray) -> np.ndarray:
        """``[N]`` at ``points [N, 2]``, bilinear between cell centres."""
        # scipy.ndimage here, not at the top: it takes a tenth of the planner's start-up to
        # import, and only planners with a map call this
        from scipy.ndimage import map_coordinates

        rc = (points[:, ::-1] - np.asarray(self.origin)[::-1]) / self.resolution  # (row, col)
        d = map_coordinates(self.values, rc.T, order=1, mode="nearest")
        top = np.asarray(self.values.shape) - 1
        inside = np.all((rc >= 0) & (rc <= top), axis=1)
        return np.where(inside, d, self.outside)

    def extent(self, below: float) -> list[np.ndarray]:
        """Two corners (x, y) of the box holding every cell closer than ``below`` to an
        obstacle; none when no cell is."""
        rows, cols = np.nonzero(self.values < below)
        if not len(rows):
            return []
        lo = np.array([cols.min(), rows.min()]) * self.resolution + self.origin
        hi = np.array([cols.max(), rows.max()]) * self.resolution + self.origin
        return [lo, hi]


def signed_distance(
    shapes: list[Shape], points: np.ndarray, field: MapObstacles | None = None
) -> np.ndarray:
    """Signed distance ``[N]`` of ``points [N, 2]`` to the union of ``shapes`` and the map's
    obstacles ``field`` (negative inside); +inf without either."""
    out = np.full(points.shape[0], np.inf) if field is None else field.distance(points)
    for s in shapes:
        d = points - np.asarray(s.centre)
        c, si = math.cos(s.yaw), math.sin(s.yaw)
        if s.kind == "halfplane":
            dist = d @ np.array([c, si])
        elif s.kind == "disk":
            dist = np.hypot(d[:, 0], d[:, 1]) - s.half[0]
        else:  # box: the distance in its own frame
            local = np.abs(np.stack([d[:, 0] * c + d[:, 1] * si, -d[:, 0] * si + d[:, 1] * c], 1))
            q = local - np.asarray(s.half)
            outside = np.hypot(np.maximum(q[:, 0], 0.0), np.maximum(q[:, 1], 0.0))
            dist = outside + np.minimum(np.maximum(q[:, 0], q[:, 1]), 0.0)
        np.minimum(out, dist, out=out)
    return out


@dataclass(frozen=True)
class Grid:
    """Cells of ``resolution`` m; cell (i, j) is centred at ``origin + (j, i) · resolution``."""

    origin: tuple[float, float]
    resolution: float
    shape: tuple[int, int]  # rows (y), columns (x)

    @classmethod
    def around(cls, points: list[np.ndarray], shapes: list[Shape], resolution: float) -> Grid:
        """A grid over the points and every bounded shape, 1 m of room around them; walls
        (half-planes) are outside it or cut it."""
        xy = [np.asarray(p, float)[:2] for p in points]
        for s in shapes:
            r = s.extent()
            if r is not None:
                xy += [np.asarray(s.centre) - r, np.asarray(s.centre) + r]
        # cell centres on multiples of the resolution: a goal at 3.75 m lies on one at 0.05 m
        lo = np.floor((np.min(xy, axis=0) - 1.0) / resolution) * resolution
        hi = np.max(xy, axis=0) + 1.0
        n = np.ceil((hi - lo) / resolution).astype(int) + 1
        return cls((float(lo[0]), float(lo[1])), resolution, (int(n[1]), int(n[0])))

    def centres(self) -> np.ndarray:
        """``[rows, cols, 2]`` the cells' centres (x, y)."""
        rows, cols = self.shape
        x = self.origin[0] + np.arange(cols) * self.resolution
        y = self.origin[1] + np.arange(rows) * self.resolution
        return np.stack(np.meshgrid(x, y), axis=-1)

    def cell(self, p: np.ndarray) -> tuple[int, int]:
        """The cell holding point ``p`` (x, y), clipped to the grid."""
        j = round((p[0] - self.origin[0]) / self.resolution)
        i = round((p[1] - self.origin[1]) / self.resolution)
        return min(max(i, 0), self.shape[0] - 1), min(max(j, 0), self.shape[1] - 1)

    def point(self, cell: tuple[int, int]) -> np.ndarray:
        return np.array(
            [
                self.origin[0] + cell[1] * self.resolution,
                self.origin[1] + cell[0] * self.resolution,
            ]
        )


def nearest_free(free: np.ndarray, cell: tuple[int, int]) -> tuple[int, int] | None:
    """``cell`` if free, else the free cell nearest to it (Euclidean, in cells); None if no cell
    is free."""
    if free[cell]:
        return cell
    idx = np.argwhere(free)
    if not len(idx):
        return None
    k = int(np.argmin(((idx - np.asarray(cell)) ** 2).sum(1)))
    return int(idx[k, 0]), int(idx[k, 1])


def astar(
    free: np.ndarray,
    start: tuple[int, int],
    goal: tuple[int, int],
    move_ok: np.ndarray | None = None,
) -> list[tuple[int, int]] | None:
    """The shortest 8-connected path of free cells from ``start`` to ``goal`` (both included),
    or None when there is none. A diagonal move needs both cells beside it free (no corner
    cutting). ``move_ok [8, rows, cols]``: whether move k (:data:`MOVES`) may leave a cell
    (e.g. the robot has room behind a pushed object); None: every move.

    A* with the octile distance, admissible and consistent on this graph, so the first time the
    goal is popped its cost is the shortest."""
    rows, cols = free.shape
    if not (free[start] and free[goal]):
        return None

    def h(c):
        dy, dx = abs(c[0] - goal[0]), abs(c[1] - goal[1])
        return max(dx, dy) + (math.sqrt(2) - 1) * min(dx, dy)

    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(h(start), 0.0, start)]
    closed = set()
    while heap:
        _, cost, c = heapq.heappop(heap)
        if c in closed:
            continue
        if c == goal:
            path = [c]
            while c in parent:
                c = parent[c]
                path.append(c)
            return path[::-1]
        closed.add(c)
        for k, (di, dj) in enumerate(MOVES):
            n = (c[0] + di, c[1] + dj)
            if not (0 <= n[0] < rows and 0 <= n[1] < cols) or not free[n] or n in closed:
                continue
            if di and dj and not (free[c[0] + di, c[1]] and free[c[0], c[1] + dj]):
                continue
            if move_ok is not None and not move_ok[k][c]:
                continue
            new = cost + MOVE_LEN[k]
            if new < g.get(n, math.inf):
                g[n] = new
                parent[n] = c
                heapq.heappush(heap, (new + h(n), new, n))
    return None


def line_free(free: np.ndarray, a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether every cell the segment a-b passes over (sampled at a third of a cell) is free."""
    n = int(3 * max(abs(b[0] - a[0]), abs(b[1] - a[1]))) + 1
    t = np.linspace(0.0, 1.0, n + 1)
    i = np.rint(a[0] + t * (b[0] - a[0])).astype(int)
    j = np.rint(a[1] + t * (b[1] - a[1])).astype(int)
    return bool(free[i, j].all())


def simplify(
    cells: list[tuple[int, int]], ok: Callable[[tuple[int, int], tuple[int, int]], bool]
) -> list[tuple[int, int]]:
    """The path's corners only: from each kept cell, the farthest later cell that ``ok`` says is
    reachable in a straight line (string pulling); first and last cells kept."""
    out = [cells[0]]
    i = 0
    while i < len(cells) - 1:
        j = len(cells) - 1
        while j > i + 1 and not ok(cells[i], cells[j]):
            j -= 1
        out.append(cells[j])
        i = j
    return out


def corners(cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The cells where the path changes its move, first and last cells kept."""
    out = [cells[0]]
    for p, c, n in zip(cells, cells[1:], cells[2:]):
        if (c[0] - p[0], c[1] - p[1]) != (n[0] - c[0], n[1] - c[1]):
            out.append(c)
    return out + cells[-1:] if len(cells) > 1 else out


@dataclass(frozen=True)
class Room:
    """Where a robot of ``radius`` must stand beside a guided object that moves one grid step:
    ``behind`` it (a push), ahead of it or at its side (a pull, holding it by suction), or
    either (``any``); :func:`handles` says where exactly. ``reach`` is how far from the
    object's centre the robot's centre stands (touching: object half-size + robot radius), and
    there the robot must be ``gap`` m clear of every obstacle."""

    mode: str  # push | pull | any
    radius: float
    reach: float
    gap: float = 0.0


def room_moves(
    grid: Grid, shapes: list[Shape], room: Room, field: MapObstacles | None = None
) -> np.ndarray:
    """``[8, rows, cols]``: whether the object may leave each cell by move k with the robot
    where ``room`` says, clear of ``shapes`` and ``field`` by its radius: behind the cell for a
    push, ahead of the next cell or beside it for a pull."""
    centres = grid.centres().reshape(-1, 2)
    rows, cols = grid.shape

    def clear_at(offset: np.ndarray) -> np.ndarray:
        clear = signed_distance(shapes, centres + offset, field) > room.radius + room.gap
        return clear.reshape(rows, cols)

    out = np.zeros((8, rows, cols), dtype=bool)
    for k, (di, dj) in enumerate(MOVES):
        d = np.array([dj, di], float) / MOVE_LEN[k]  # (x, y) unit direction
        step = d * MOVE_LEN[k] * grid.resolution
        side = np.array([-d[1], d[0]])
        ok = np.zeros((rows, cols), dtype=bool)
        if room.mode in ("push", "any"):
            ok |= clear_at(-d * room.reach)
        if room.mode in ("pull", "any"):
            for offset in (d * room.reach, side * room.reach, -side * room.reach):
                ok |= clear_at(step + offset)
        out[k] = ok
    return out


def handles(
    cells_xy: np.ndarray, shapes: list[Shape], room: Room, field: MapObstacles | None = None
) -> np.ndarray:
    """``[M, 2]``: where the robot's centre stands, relative to the object's, at each point of
    a dense path ``cells_xy [M, 2]``, clear of ``shapes`` and ``field`` by the robot's radius:
    behind the move for a push; for a pull ahead of it, else at the side with more room, else
    behind it (a diagonal move into a corner leaves neither: :func:`room_moves` lets A* plan no
    such move, but does not check a path's first cell, where the object starts). Chosen from the
    goal backwards, keeping the place of the next point while it is still clear (and, for a
    push, still behind the move). A pull keeps it on any side of the move: the robot holds the
    box by suction and cannot go round it without dragging it along, so a robot that must end
    beside a box pulled into a corner holds it from that side all the way, dragging it sideways
    and, where the path turns, pushing it. NaN where no place is clear."""
    moves = np.diff(cells_xy, axis=0)
    moves = np.concatenate([moves, moves[-1:]]) if len(moves) else np.array([[1.0, 0.0]])
    d = moves / np.maximum(np.linalg.norm(moves, axis=1, keepdims=True), 1e-12)
    out = np.full(cells_xy.shape, np.nan)

    def clear(p: np.ndarray) -> float:
        return float(signed_distance(shapes, p[None], field)[0])

    def allowed(offset: np.ndarray, dm: np.ndarray) -> bool:
        return room.mode != "push" or float(offset @ dm) / room.reach < -0.7

    prev = None
    for m in range(len(cells_xy) - 1, -1, -1):
        p, dm = cells_xy[m], d[m]
        need = room.radius + room.gap
        if prev is not None and allowed(prev, dm) and clear(p + prev) > need:
            out[m] = prev
            continue
        side = np.array([-dm[1], dm[0]])
        first = {"push": [-dm], "pull": [dm], "any": [-dm, dm]}[room.mode]
        options = [o * room.reach for o in first]
        sides = [] if room.mode == "push" else [side * room.reach, -side * room.reach]
        sides.sort(key=lambda o: -clear(p + o))
        last = [-dm * room.reach] if room.mode == "pull" else []
        prev = next((o for o in options + sides + last if clear(p + o) > need), None)
        if prev is not None:
            out[m] = prev
    return out


@dataclass(frozen=True)
class PathResult:
    """A path's corners ``[N, 2]`` (x, y; the first at the start, the last at the goal) or None
    when the goal cannot be reached; ``reason`` says why. With room for a robot, also every
    cell's centre on the way ``dense [M, 2]`` and where the robot stands there relative to the
    object, ``handles [M, 2]`` (:func:`handles`)."""

    points: np.ndarray | None
    reason: str = ""
    dense: np.ndarray | None = None
    handles: np.ndarray | None = None

    @property
    def length(self) -> float:
        if self.points is None:
            return math.inf
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def plan(
    shapes: list[Shape],
    start: np.ndarray,
    goal: np.ndarray,
    resolution: float,
    radius: float,
    room: Room | None = None,
    field: MapObstacles | None = None,
) -> PathResult:
    """Grid A* for a body of ``radius`` (its centre stays ``radius`` clear of every shape and
    of the map's obstacles ``field``) from ``start`` to ``goal`` (x, y), with ``room`` for a
    robot beside it when it is an object moved by one. A start or goal inside the inflated
    obstacles (an object pressed into a corner) is moved to the nearest free cell; the path
    then begins or ends there. The grid holds the map's cells closer than ``radius`` to an
    obstacle as it holds the shapes."""
    start, goal = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
    seen = field.extent(radius) if field is not None else []
    grid = Grid.around([start, goal, *seen], shapes, resolution)
    clearance = signed_distance(shapes, grid.centres().reshape(-1, 2), field).reshape(grid.shape)
    free = clearance > radius
    s, g = nearest_free(free, grid.cell(start)), nearest_free(free, grid.cell(goal))
    if s is None or g is None:
        return PathResult(None, "no free cell: the body does not fit anywhere")
    move_ok = room_moves(grid, shapes, room, field) if room is not None else None
    cells = astar(free, s, g, move_ok)
    if cells is None:
        return PathResult(None, "the goal cannot be reached")
    dense = hands = None
    if move_ok is None:
        cells = simplify(cells, lambda a, b: line_free(free, a, b))
    else:  # a straight line may cross cells without room: only runs of one move are merged
        dense = np.array([grid.point(c) for c in cells])
        hands = handles(dense, shapes, room, field)
        cells = corners(cells)
    points = [grid.point(c) for c in cells]
    # the path starts and ends at the exact points when their cells were free
    points[0] = start if s == grid.cell(start) else points[0]
    points[-1] = goal if g == grid.cell(goal) else points[-1]
    if len(points) == 1:
        points.append(points[0])
    return PathResult(np.array(points), dense=dense, handles=hands)
