"""The robot's collision spheres (shared/robots, planner_client/spheres.py), the term that looks
them up in the planner's map (planner_client/costs/perceived.py) and the guide planning on the
map (planner_client/guide.py, global_path.py): spheres that hold the shipped robots' geoms,
the term against a brute-force loop, a wall only the map knows kept off in a lock-step loop and
gone round by the guide."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from planner_client.costs import RolloutBatch
from planner_client.global_path import MapObstacles, plan
from planner_client.perception.field import DistanceField
from planner_client.problem import build_problem, check_terms
from planner_client.spheres import SITE_PREFIX, derive_spheres, robot_spheres
from shared.config import ConfigError, Section
from shared.frames import FrameResolver
from shared.robots import ROBOT_DIR, get_robot, parse_robot
from shared.scenario import load_scenario, parse_scenario

F64 = torch.float64
RES = 0.05


class Fixed:
    """A field source that always gives one field."""

    def __init__(self, field: DistanceField | None):
        self.field = field

    def latest(self) -> DistanceField | None:
        return self.field


def wall_field(x0: float, half_y: float = 10.0, dims: int = 2) -> DistanceField:
    """The signed distance to the half-space x >= x0 (|y| <= half_y: a wall's end beyond
    that), on a grid over [-4, 4]² (and z in [0, 3] for a 3-D field)."""
    xs = torch.arange(-4.0, 4.0 + 1e-9, RES, dtype=F64)
    y, x = torch.meshgrid(xs, xs, indexing="ij")  # rows: y, columns: x
    beyond = (y.abs() - half_y).clamp(min=0.0)
    d = torch.where(beyond > 0, torch.hypot((x0 - x).clamp(min=0.0), beyond), x0 - x)
    if dims == 2:
        return DistanceField(d, (-4.0, -4.0), RES)
    zs = torch.arange(0.0, 3.0 + 1e-9, RES, dtype=F64)
    return DistanceField(d.expand(len(zs), *d.shape).clone(), (-4.0, -4.0, 0.0), RES)


def _geom_points(model: mujoco.MjModel, g: int, rng: np.random.Generator) -> np.ndarray:
    """Points ``[N, 3]`` of geom ``g``'s volume and surface in its body's frame."""
    size, t = model.geom_size[g], int(model.geom_type[g])
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
        local = np.concatenate([rng.uniform(-1, 1, (2000, 3)), corners]) * size
    else:
        r, h = size[0], size[1] if t != mujoco.mjtGeom.mjGEOM_SPHERE else 0.0
        cap = r if t != mujoco.mjtGeom.mjGEOM_CYLINDER else 0.0
        p = rng.uniform(-1, 1, (20000, 3)) * [r, r, h + cap]
        radial = np.hypot(p[:, 0], p[:, 1])
        if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
            rim = np.stack([np.cos(p[:, 0] * 4) * r, np.sin(p[:, 0] * 4) * r, p[:, 2]], 1)
            local = np.concatenate([p[radial <= r], rim, rim * [1, 1, 0] + [0, 0, h]])
        else:  # within r of the segment on z, |z| <= h
            out = np.hypot(radial, np.clip(np.abs(p[:, 2]) - h, 0, None))
            local = p[out <= r]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    return local @ rot.reshape(3, 3).T + model.geom_pos[g]


@pytest.mark.parametrize(
    "name, counts",
    [
        ("point_robot", {"robot": 1}),
        ("panda", {"panda_link0": 4, "panda_link5": 5, "panda_hand": 6}),
        ("mobile_panda", {"chassis": 2, "panda_link0": 4, "panda_leftfinger": 4}),
    ],
)
def test_spheres_derived_from_a_shipped_robots_geoms_hold_them(name, counts):
    robot = get_robot(name)
    model = mujoco.MjModel.from_xml_path(str(robot.path))
    derived = derive_spheres(model)
    spheres = robot_spheres(model, FrameResolver(model, robot.frame), robot)
    assert {b: len(derived[b]) for b in counts} == counts
    declared = dict(robot.spheres)  # a body the robot file lists has those instead
    assert len(spheres) == sum(len(declared.get(b, v)) for b, v in derived.items())
    assert len({s.site for s in spheres}) == len(spheres)
    rng = np.random.default_rng(0)
    for body in range(1, model.nbody):
        start, n = model.body_geomadr[body], model.body_geomnum[body]
        balls = np.array(derived.get(model.body(body).name, np.zeros((0, 4))))
        for g in range(start, start + n):
            if not (model.geom_contype[g] or model.geom_conaffinity[g]):
                continue
            pts = _geom_points(model, g, rng)
            gap = np.linalg.norm(pts[:, None] - balls[None, :, :3], axis=-1) - balls[:, 3]
            assert gap.min(axis=1).max() <= 1e-9, (name, model.geom(g).name)
    # a long link is several spheres, none much fatter than the link
    assert max(r for _, _, _, r in derived.get("panda_link5", [(0, 0, 0, 0)])) < 0.062
    if name == "point_robot":  # the disc of radius 0.2 and half height 0.1, one sphere
        assert spheres[0].pos == (0.0, 0.0, 0.12)
        assert spheres[0].radius == pytest.approx(math.hypot(0.2, 0.1))


def test_a_scenarios_model_gives_its_robot_the_spheres_of_the_robots_own_model():
    for name in ("navigation", "pick_place", "mobile_pick_place"):
        sc = load_scenario(name)
        problem = build_problem(sc)
        alone = mujoco.MjModel.from_xml_path(str(sc.robot.spec.path))
        assert robot_spheres(problem.model, problem.resolve) == robot_spheres(
            alone, FrameResolver(alone, sc.robot.spec.frame)
        )


def _spheres_of(spec):
    model = mujoco.MjModel.from_xml_path(str(spec.path))
    return robot_spheres(model, FrameResolver(model, spec.frame), spec)


def _robot_file(spheres) -> Section:
    return Section(
        {
            "mjcf": "point_robot.xml",
            "frame": "robot",
            "controls": {"vel_x": "m/s", "vel_y": "m/s"},
            "spheres": spheres,
        },
        "r.yaml",
    )


def test_declared_spheres_replace_a_bodys_own_and_are_checked():
    spec = parse_robot(
        _robot_file({"robot": [[0.0, 0.0, 0.1, 0.25], [0.1, 0, 0.1, 0.05]]}), "r", ROBOT_DIR
    )
    got = _spheres_of(spec)
    assert [(s.body, s.pos, s.radius) for s in got] == [
        ("robot", (0.0, 0.0, 0.1), 0.25),
        ("robot", (0.1, 0.0, 0.1), 0.05),
    ]
    assert _spheres_of(parse_robot(_robot_file({"robot": []}), "r", ROBOT_DIR)) == ()
    for bad, key, message in [
        ({"wheel": [[0, 0, 0, 0.1]]}, "spheres.wheel", "no body 'wheel'"),
        ({"robot": [[0, 0, 0, 0.0]]}, "spheres.robot[0]", "radius must be > 0"),
        ({"robot": [[0, 0, float("nan"), 0.1]]}, "spheres.robot[0]", "finite"),
        ({"robot": [[0, 0, 0.1]]}, "spheres.robot[0]", "needs 4 numbers"),
        ({"robot": [0, 0, 0, 0.1]}, "spheres.robot[0]", "wrong type"),
        ({"robot": 0.1}, "spheres.robot", "wrong type"),
    ]:
        with pytest.raises(ConfigError) as exc:
            parse_robot(_robot_file(bad), "r", ROBOT_DIR)
        assert exc.value.path == key and message in str(exc.value), (bad, str(exc.value))


def _with_term(name: str, term: dict, **planner) -> dict:
    raw = load_scenario(name).raw
    objective = next(iter(raw["objectives"]))
    terms = raw["objectives"][objective]["terms"]
    raw["objectives"] = {
        **raw["objectives"],
        objective: {**raw["objectives"][objective], "terms": [*terms, term]},
    }
    raw["planner"] = {**raw["planner"], **planner}
    raw.pop("base", None)
    return raw


def _batch(problem, qpos: np.ndarray) -> RolloutBatch:
    """The problem's sensor values at each pose of ``qpos [S, T, nq]`` (its other joints
    at the start)."""
    model = problem.model
    data = mujoco.MjData(model)
    rows = []
    for q in qpos.reshape(-1, qpos.shape[-1]):
        data.qpos[: len(q)] = q
        mujoco.mj_forward(model, data)
        rows.append(data.sensordata.copy())
    sd = torch.tensor(np.array(rows), dtype=F64).reshape(*qpos.shape[:2], -1)
    return RolloutBatch(sd, torch.zeros(*qpos.shape[:2], model.nu, dtype=F64), problem.columns, 0.1)


def test_scenarios_without_the_term_get_no_sites_and_with_it_a_site_per_sphere():
    plain = build_problem(load_scenario("navigation"))
    assert not any(
        plain.model.site(i).name.startswith(SITE_PREFIX) for i in range(plain.model.nsite)
    )
    term = {"term": "perceived_clearance", "margin": 0.1, "bodies": ["panda_hand"]}
    problem = build_problem(parse_scenario(_with_term("pick_place", term), "t.yaml"))
    names = [problem.model.site(i).name for i in range(problem.model.nsite)]
    assert [n for n in names if n.startswith(SITE_PREFIX)] == [
        f"{SITE_PREFIX}__panda_hand__{i}" for i in range(6)
    ]


ARM = {"bodies": ["panda_link7", "panda_hand", "panda_leftfinger"]}  # the moving end


@pytest.mark.parametrize("scenario, dims, params", [("navigation", 2, {}), ("pick_place", 3, ARM)])
def test_the_term_is_zero_far_and_matches_a_loop_inside_the_margin(scenario, dims, params):
    margin = 0.1
    raw = _with_term(scenario, {"term": "perceived_clearance", "margin": margin, **params})
    problem = build_problem(parse_scenario(raw, "t.yaml"))
    term = problem.objectives[next(iter(problem.objectives))].terms[-1].term
    check_terms(problem)  # no field yet: zeros [S, T]
    model, data = problem.model, mujoco.MjData(problem.model)
    nq = 2 if dims == 2 else 7
    start = data.qpos[:nq].copy()
    qpos = start + np.random.default_rng(1).uniform(-0.6, 0.6, (4, 3, nq))
    batch = _batch(problem, qpos)
    assert torch.count_nonzero(term(batch)) == 0
    problem.field_source.connect(Fixed(wall_field(3.9, dims=dims)))  # far from every sphere
    assert torch.count_nonzero(term(batch)) == 0
    # a wall that half the poses reach into the margin of, by their foremost sphere
    radii = torch.tensor([sp.radius for sp in term.spheres], dtype=F64)
    front = (term.centres(batch)[..., 0] + radii).amax(-1)  # [S, T]
    wall = float(front.median()) + margin / 2
    problem.field_source.connect(Fixed(wall_field(wall, dims=dims)))
    check_terms(problem)
    got = term(batch)
    assert got.shape == (4, 3) and got.dtype == F64
    assert (got > 0).any() and (got == 0).any()
    expected = torch.zeros(4, 3, dtype=F64)
    for s in range(4):
        for t in range(3):
            data.qpos[:nq] = qpos[s, t]
            mujoco.mj_kinematics(model, data)
            for sp in term.spheres:
                body = model.body(sp.body).id
                centre = data.xpos[body] + data.xmat[body].reshape(3, 3) @ sp.pos
                gap = (wall - centre[0]) - sp.radius  # the wall is a half-space: d = x0 - x
                expected[s, t] += max(0.0, margin - gap) ** 2 / margin**2
    torch.testing.assert_close(got, expected)


def test_the_term_grows_as_the_robot_goes_into_the_margin():
    raw = _with_term("navigation", {"term": "perceived_clearance", "margin": 0.1})
    problem = build_problem(parse_scenario(raw, "t.yaml"))
    term = problem.objectives["navigate"].terms[-1].term
    problem.field_source.connect(Fixed(wall_field(1.0)))
    x = np.linspace(0.5, 1.0, 12)  # the sphere (r 0.224) enters the margin at x = 0.676
    batch = _batch(problem, np.stack([x, np.zeros_like(x)], -1).reshape(4, 3, 2))
    cost = term(batch).reshape(-1)
    inside = torch.as_tensor(x > 1.0 - 0.1 - math.hypot(0.2, 0.1))
    assert (cost[~inside] == 0).all() and (cost[inside] > 0).all()
    assert (cost[inside].diff() > 0).all()
    assert cost[-1] > 1.0  # past touching: more than 1


def test_the_term_refuses_bodies_without_spheres_and_a_missing_margin():
    for term, message in [
        (
            {"term": "perceived_clearance", "margin": 0.1, "bodies": ["goal"]},
            "no collision spheres",
        ),
        ({"term": "perceived_clearance", "margin": 0.1, "bodies": []}, "no bodies"),
        ({"term": "perceived_clearance"}, "missing required key"),
    ]:
        with pytest.raises(ConfigError) as exc:
            build_problem(parse_scenario(_with_term("navigation", term), "t.yaml"))
        assert message in str(exc.value)


def _wall_run(with_term: bool, steps: int = 45) -> float:
    """The robot's largest x in a lock-step loop towards a goal at (2, 0) behind a wall at
    x = 1 that only the map knows (its MuJoCo model has none)."""
    from planner_client.build import build_controller
    from server.inprocess import build_episode

    raw = load_scenario("navigation").raw
    raw["world"] = {
        **raw["world"],
        "objects": [{**raw["world"]["objects"][-1], "pos": [2.0, 0.0, 0.005]}],
    }
    raw["planner"] = {**raw["planner"], "samples": 48}
    terms = [{"term": "distance", "a": "robot", "b": "goal", "axes": "xy"}]
    if with_term:
        terms.append({"term": "perceived_clearance", "margin": 0.1, "weight": 20.0})
    raw["objectives"] = {"navigate": {"terms": terms}}
    sc = parse_scenario(raw, str(Path("wall.yaml").absolute()))
    controller = build_controller(sc, threads=2, seed=0)
    controller.motion.problem.field_source.connect(Fixed(wall_field(1.0)))
    episode = build_episode(sc, seed=0)
    controller.begin("lockstep", episode.dt)
    state = episode.publish()
    reach = -math.inf
    for _ in range(steps):
        episode.play(controller.step(state))
        state = episode.publish()
        reach = max(reach, float(state.qpos[0]))
    controller.close()
    episode.close()
    return reach


def test_a_wall_only_the_map_knows_stops_the_robot_that_drives_through_it_without_the_term():
    assert _wall_run(with_term=False) > 1.5  # the model has no wall: straight through
    assert _wall_run(with_term=True) < 1.0 - 0.2  # the disc (r 0.2) never reaches it


def bar_field(half_x: float, half_y: float) -> DistanceField:
    """The distance to a bar |x| <= half_x, |y| <= half_y (0 inside), on a grid over [-4, 4]²."""
    xs = torch.arange(-4.0, 4.0 + 1e-9, RES, dtype=F64)
    y, x = torch.meshgrid(xs, xs, indexing="ij")
    d = torch.hypot((x.abs() - half_x).clamp(min=0.0), (y.abs() - half_y).clamp(min=0.0))
    return DistanceField(d, (-4.0, -4.0), RES)


def test_the_global_path_goes_round_a_bar_only_the_map_knows():
    start, goal = np.array([0.0, -2.0]), np.array([0.0, 2.0])
    assert np.abs(plan([], start, goal, 0.1, 0.3).points[:, 0]).max() < 1e-9
    bar = bar_field(1.5, 0.1)
    field = MapObstacles(bar.values.numpy(), (-4.0, -4.0), RES)
    d = field.distance(np.array([[0.0, 0.0], [0.0, 0.5], [2.0, 0.0], [0.0, 9.0]]))
    np.testing.assert_allclose(d, [0.0, 0.4, 0.5, 1e3], atol=1e-9)
    res = plan([], start, goal, 0.1, 0.3, field=field)
    assert res.points is not None and np.abs(res.points[:, 0]).max() > 1.5 + 0.3
    assert (field.distance(res.points) > 0.3).all()


def test_the_guide_plans_again_round_a_bar_that_a_new_map_shows_across_its_path():
    from planner_client.build import build_controller
    from server.inprocess import build_episode

    raw = load_scenario("navigation_trap_guided").raw
    goal = next(o for o in raw["world"]["objects"] if o["name"] == "goal")
    raw["world"] = {**raw["world"], "objects": [goal], "randomize": []}
    raw["metrics"] = {}
    raw.pop("base", None)
    sc = parse_scenario(raw, str(Path("open.yaml").absolute()))
    controller = build_controller(sc, threads=2, seed=0)
    episode = build_episode(sc, seed=0)
    controller.begin("lockstep", episode.dt)
    guide = controller.guide
    state = episode.publish()
    episode.play(controller.step(state))
    assert np.abs(guide.state.points[:, 0]).max() < 0.1  # nothing in the way: straight up
    version = guide.state.version
    controller.motion.problem.field_source.connect(Fixed(bar_field(1.5, 0.1)))
    for _ in range(3):  # asked for at the next step, taken at the one after
        state = episode.publish()
        episode.play(controller.step(state))
    assert guide.state.version > version
    assert np.abs(guide.state.points[:, 0]).max() > 1.5 + guide.radius
    controller.close()
    episode.close()
