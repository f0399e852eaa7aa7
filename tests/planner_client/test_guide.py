"""The global guide (shared/scenario/guide.py, planner_client/guide.py and global_path.py):
A* round a U and blocked when closed, room for a robot behind a box,
the path recomputed after an obstacle is moved while planning goes on, the terms' values, and
the scenario errors of a faulty guide."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from planner_client.costs import TERMS, RolloutBatch, TermContext
from planner_client.global_path import Room, Shape, astar, handles, plan, signed_distance
from planner_client.guide import PathTensors, project
from planner_client.sensors import SensorColumns, SensorRequest
from shared import protocol as P
from shared.config import ConfigError, Section
from shared.scenario import load_scenario, parse_scenario

F64 = torch.float64

# the arena's four walls at ±4 m, as the guide sees them (half-planes facing in)
WALLS = [
    Shape("halfplane", (0.0, 4.0), yaw=-math.pi / 2),
    Shape("halfplane", (0.0, -4.0), yaw=math.pi / 2),
    Shape("halfplane", (4.0, 0.0), yaw=math.pi),
    Shape("halfplane", (-4.0, 0.0), yaw=0.0),
]
# a U open to the south around the origin: the back at y = 1, the arms at x = ±1.2
U = [
    Shape("box", (0.0, 1.0), (1.3, 0.1)),
    Shape("box", (-1.2, 0.1), (0.1, 0.8)),
    Shape("box", (1.2, 0.1), (0.1, 0.8)),
]


def test_signed_distance_of_a_box_a_disk_and_a_wall():
    pts = np.array([[2.0, 0.0], [0.0, 0.0], [0.0, 3.5]])
    box = [Shape("box", (0.0, 0.0), (1.0, 0.5))]
    np.testing.assert_allclose(signed_distance(box, pts[:2]), [1.0, -0.5])
    turned = [Shape("box", (0.0, 0.0), (1.0, 0.5), yaw=math.pi / 2)]
    np.testing.assert_allclose(signed_distance(turned, pts[:1]), [1.5])
    np.testing.assert_allclose(
        signed_distance([Shape("disk", (1.0, 0.0), (0.5, 0.0))], pts[:1]), [0.5]
    )
    np.testing.assert_allclose(signed_distance(WALLS, pts[2:]), [0.5])


def test_astar_finds_the_way_round_a_u_and_says_blocked_when_closed():
    start, goal = np.array([0.0, -2.0]), np.array([0.0, 2.5])
    res = plan(WALLS + U, start, goal, resolution=0.1, radius=0.25)
    assert res.points is not None
    # longer than the straight 4.5 m, round an arm, and never inside the U's inflated shapes
    assert res.length > 5.5
    assert np.abs(res.points[:, 0]).max() > 1.3
    dense = np.concatenate([np.linspace(a, b, 50) for a, b in zip(res.points[:-1], res.points[1:])])
    assert signed_distance(U, dense).min() > 0.25 - 0.1  # a cell's half diagonal at most
    np.testing.assert_allclose(res.points[[0, -1]], [start, goal])
    closed = U + [Shape("box", (0.0, -0.8), (1.3, 0.1))]  # a lid: the goal is walled in
    inside = plan(WALLS + closed, np.array([0.0, 0.2]), goal, resolution=0.1, radius=0.25)
    assert inside.points is None and "cannot be reached" in inside.reason


def test_astar_on_a_small_grid_takes_no_diagonal_through_a_corner():
    free = np.ones((3, 3), dtype=bool)
    free[0, 1] = free[1, 0] = False
    free[1, 1] = True
    # (0, 0) to (1, 1) only by the diagonal, between two occupied cells: no way
    assert astar(free, (0, 0), (1, 1)) is None
    free[0, 1] = True
    assert astar(free, (0, 0), (1, 1)) == [(0, 0), (0, 1), (1, 1)]


def test_a_box_in_a_corner_has_no_room_to_be_pushed_until_it_is_out():
    goal = np.array([-3.75, 3.75])
    room = Room("push", radius=0.2, reach=0.4)
    stuck = plan(WALLS, np.array([3.75, 3.75]), goal, 0.05, 0.2, room)
    assert stuck.points is None  # the robot cannot get east or north of it
    out = plan(WALLS, np.array([3.25, 3.75]), goal, 0.05, 0.2, room)
    assert out.points is not None
    np.testing.assert_allclose(out.handles[0], [0.4, 0.0])  # behind it, to push it west
    # a pull into the far corner ends with the robot beside the box, and holds it there
    pull = plan(WALLS, np.array([3.75, 3.75]), goal, 0.05, 0.2, Room("pull", 0.2, 0.4))
    np.testing.assert_allclose(pull.handles[[0, -1]], [[0.0, -0.4], [0.0, -0.4]], atol=1e-9)


def test_a_pull_into_a_corner_keeps_one_side_all_the_way_and_pushes_where_no_side_is_clear():
    # corner 1: the goal 0.25 m from two walls; no place ahead of the box there, and the path
    # ends along the east wall with the robot west of the box
    goal = np.array([3.75, 3.75])
    pull = plan(WALLS, np.array([2.15, 1.75]), goal, 0.05, 0.2, Room("pull", 0.2, 0.4, 0.02))
    assert pull.points is not None
    np.testing.assert_allclose(pull.points[-1], goal)
    # suction holds the box on every side: the robot holds it from the west from the start,
    # behind-side while the box moves north-east, rather than going round it at the end
    np.testing.assert_allclose(pull.handles, np.tile([-0.4, 0.0], (len(pull.handles), 1)))
    # a last move diagonal into the corner: neither ahead nor at either side is clear, so
    # behind it (a push of the box it holds), not NaN
    diagonal = np.array([[3.65, 3.65], [3.7, 3.7], [3.75, 3.75]])
    hands = handles(diagonal, WALLS, Room("pull", 0.2, 0.4, 0.02))
    np.testing.assert_allclose(hands, np.tile([-0.4, -0.4], (3, 1)) / math.sqrt(2))


def test_progress_and_distance_along_a_path():
    path = PathTensors.of(
        plan([], np.array([0.0, 0.0]), np.array([2.0, 0.0]), 0.1, 0.1), np.array([2.0, 0.0])
    )
    p = torch.tensor([[[0.5, 0.3], [2.5, 0.0]]], dtype=F64)  # [1, 2, 2]
    dist, left = project(p, path)
    torch.testing.assert_close(dist, torch.tensor([[0.3, 0.5]], dtype=F64))
    torch.testing.assert_close(left, torch.tensor([[1.5, 0.0]], dtype=F64))
    blocked = PathTensors.of(None, np.array([2.0, 0.0]))
    dist, left = project(p, blocked)
    torch.testing.assert_close(left, torch.tensor([[math.hypot(1.5, 0.3), 0.5]], dtype=F64))
    assert not dist.any()


def _with_guide(guide, **more) -> dict:
    raw = load_scenario("navigation_trap_guided").raw
    raw = {**raw, "guide": guide, **more}
    raw.pop("base", None)
    return raw


@pytest.mark.parametrize(
    "guide, key, message",
    [
        ({"for": "goal", "goal": "goal"}, "guide.for", "not the robot or a free object"),
        ({"for": "u_back", "goal": "goal"}, "guide.for", "not the robot or a free object"),
        ({"for": "robot", "goal": "goal", "method": "rrt"}, "guide.method", "one of: astar"),
        ({"for": "robot", "goal": "goal", "room": "push"}, "guide.room", "object the robot"),
        ({"for": "robot", "goal": "goal", "resolution": 0}, "guide.resolution", "must be > 0"),
        ({"for": "robot", "goal": "goal", "lookahed": 1}, "guide.lookahed", "unknown key"),
        ({"for": "robot"}, "guide.goal", "missing"),
    ],
)
def test_a_faulty_guide_is_refused_naming_its_key(guide, key, message):
    with pytest.raises(ConfigError, match=message) as err:
        parse_scenario(_with_guide(guide), "trap.yaml")
    assert key in str(err.value)


def test_a_guide_on_the_warp_backend_and_a_guide_term_without_a_guide_are_refused():
    raw = _with_guide({"for": "robot", "goal": "goal"})
    raw["planner"] = {**raw["planner"], "backend": "warp"}
    with pytest.raises(ConfigError, match="warp"):
        parse_scenario(raw, "trap.yaml")
    from planner_client.planner_check import scenario_errors

    raw = load_scenario("navigation_trap").raw
    sc_errors = scenario_errors(_write(raw, "guide_progress"))
    assert any("has none" in str(e) for e in sc_errors)


def _write(raw: dict, term: str):
    import tempfile

    import yaml

    raw = {**raw, "objectives": {"navigate": {"terms": [{"term": term, "a": "robot"}]}}}
    f = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    yaml.safe_dump(raw, f)
    f.close()
    return f.name


def test_the_path_is_recomputed_after_an_obstacle_is_moved_while_planning_goes_on():
    from planner_client.build import build_controller
    from server.inprocess import build_episode

    controller = build_controller("navigation_trap_guided", threads=2, seed=0)
    episode = build_episode("navigation_trap_guided", seed=0)
    controller.begin("lockstep", episode.dt)
    guide = controller.guide
    state = episode.publish()
    commands = []
    for _ in range(3):
        commands.append(controller.step(state))
        episode.play(commands[-1])
        state = episode.publish()
    before = guide.state.version
    assert guide.state.exists and np.abs(guide.state.points[:, 0]).max() > 1.3  # round the U
    # the U's back is taken away: the way is straight through, and the path is planned again
    episode.move("u_back", np.array([3.0, -3.0, 0.2]))
    state = episode.publish()
    for _ in range(4):  # a bounded number of planner steps, each answered with a plan
        commands.append(controller.step(state))
        episode.play(commands[-1])
        state = episode.publish()
    assert all(c is not None and c.plan_ctrl is not None for c in commands)
    assert guide.state.version > before
    assert np.abs(guide.state.points[:, 0]).max() < 1.0  # straight up between the arms
    # viewers get the path's corners with the diagnostics
    diag = P.decode(P.encode(controller.diagnostics()), "diagnostics")
    np.testing.assert_allclose(diag.guide[:, :2], guide.state.points)
    controller.close()
    episode.close()


@pytest.mark.slow
def test_the_guided_robot_gets_out_of_the_trap():
    import functools

    from planner_client.build import build_controller
    from server.inprocess import run_episode

    result = run_episode(
        "navigation_trap_guided", functools.partial(build_controller, threads=2), seed=0
    )
    assert result.status == "success"
    assert result.summary["metrics"]["collisions"] == 0


def test_progress_term_reads_the_guides_path():
    sc = load_scenario("navigation_trap_guided")
    from planner_client.problem import build_problem

    problem = build_problem(sc)
    term = next(
        t for o in problem.objectives.values() for t in [w.term for w in o.terms]
    )  # any term builds; the guide's own terms from their registry entries:
    assert term is not None
    ctx_guide = problem.guide
    ctx = TermContext("t.yaml", problem.resolve, [], problem.actuators, guide=ctx_guide)
    prog = TERMS["guide_progress"].from_params(Section({}, "t.yaml", "o"), ctx)
    assert prog.a == "robot"
    ctx_guide.path = PathTensors.of(
        plan([], np.array([0.0, -2.5]), np.array([0.0, 2.5]), 0.1, 0.2), np.array([0.0, 2.5])
    )
    req = SensorRequest("framepos", "robot")
    sd = torch.tensor([[[0.0, 0.0, 0.1], [0.5, 1.5, 0.1]]], dtype=F64)
    batch = RolloutBatch(
        sd, torch.zeros(1, 2, 2, dtype=F64), SensorColumns({req: slice(0, 3)}), 0.1
    )
    torch.testing.assert_close(prog(batch), torch.tensor([[2.5, 1.0]], dtype=F64))
    dist = TERMS["guide_distance"].from_params(Section({}, "t.yaml", "o"), ctx)
    torch.testing.assert_close(dist(batch), torch.tensor([[0.0, 0.5]], dtype=F64))


def test_a_walled_in_goal_says_blocked_to_the_observers_and_leaves_the_goal_as_sub_goal():
    from planner_client.build import build_controller
    from server.inprocess import build_episode

    raw = load_scenario("navigation_trap_guided").raw
    lid = {"name": "lid", "shape": "box", "size": [1.3, 0.1, 0.2], "pos": [0.0, -0.8, 0.2]}
    raw["world"] = {**raw["world"], "objects": [*raw["world"]["objects"], lid], "randomize": []}
    raw["world"]["objects"][3] = {**raw["world"]["objects"][3], "pos": [0.0, 0.1, 0.005]}
    raw.pop("base", None)
    sc = parse_scenario(raw, "walled.yaml")
    controller = build_controller(sc, threads=2, seed=0)
    episode = build_episode(sc, seed=0)
    controller.begin("lockstep", episode.dt)
    assert controller.step(episode.publish()) is not None
    assert controller.guide.extras() == {"guide": 0.0, "guide_length": math.inf}
    goal = controller.motion.problem.resolve("goal").pos(controller.mirror.data)
    subgoal = controller.motion.problem.model.body_pos[controller.guide.site_body]
    np.testing.assert_allclose(subgoal[:2], goal[:2])
    controller.close()
    episode.close()
