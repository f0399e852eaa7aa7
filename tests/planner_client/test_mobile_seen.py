"""mobile_pick_place_seen (issue 56): a box the planner does not know, in the mobile Panda's way
between the tables, seen only by a lidar on the chassis. The planner's model lacks the box, its
clearance term reads the chassis' spheres alone, a few lock-step steps put the box into the map
the term reads, and the guide for the chassis (a body of the robot) plans round it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from planner_client.build import build_controller
from planner_client.costs.perceived import PerceivedClearance
from planner_client.global_path import Shape, signed_distance
from planner_client.guide import resample
from planner_client.problem import build_problem
from server.inprocess import build_episode
from shared.config import ConfigError
from shared.scenario import load_scenario, parse_scenario
from tests.helpers import play

NAME = "mobile_pick_place_seen"
BOX = Shape("box", (0.85, 1.5), (0.2, 0.2))  # the scenario's box from above
CHASSIS = (0.3, 0.25)  # the chassis box's half sides in x and y, m
GUIDE_RADIUS = 0.39  # the scenario's guide.radius: the chassis' half diagonal
STAND = (0.7, 2.6)  # the guide's goal, stand_b


@pytest.fixture(scope="module")
def seen():
    return load_scenario(NAME)


def _terms(problem, name: str) -> list[PerceivedClearance]:
    """The ``perceived_clearance`` terms of objective ``name``."""
    terms = problem.objectives[name].terms
    return [wt.term for wt in terms if isinstance(wt.term, PerceivedClearance)]


def test_the_box_is_the_worlds_alone_and_the_term_reads_the_chassis(seen):
    problem = build_problem(seen)
    assert mujoco.mj_name2id(problem.model, mujoco.mjtObj.mjOBJ_BODY, "box") == -1
    assert "box" in {o.name for o in seen.world.objects if o.perceived}
    for name in set(seen.action_objectives.values()):  # each objective the task plans with
        (term,) = _terms(problem, name)
        assert {sp.body for sp in term.spheres} == {"chassis"}
        for sp in term.spheres:
            assert mujoco.mj_name2id(problem.model, mujoco.mjtObj.mjOBJ_SITE, sp.site) >= 0


def test_the_chassis_spheres_hold_its_footprint_and_stand_out_little(seen):
    problem = build_problem(seen)
    spheres = _terms(problem, "carry_seen")[0].spheres
    centres = np.array([sp.pos[:2] for sp in spheres])  # [n, 2]
    radii = np.array([sp.radius for sp in spheres])
    hx, hy = CHASSIS
    t = np.linspace(-1.0, 1.0, 41)
    rim = np.concatenate(
        [np.stack([np.full_like(t, s * hx), t * hy], 1) for s in (-1, 1)]
        + [np.stack([t * hx, np.full_like(t, s * hy)], 1) for s in (-1, 1)]
    )  # [164, 2] the chassis' outline
    gap = np.linalg.norm(rim[:, None] - centres[None], axis=-1) - radii  # [164, n]
    assert (gap.min(axis=1) <= 1e-9).all()  # every point of the outline inside a sphere
    reach_x = np.abs(centres[:, 0]) + radii
    reach_y = np.abs(centres[:, 1]) + radii
    assert reach_x.max() - hx < 0.05 and reach_y.max() - hy < 0.05


def test_lockstep_steps_map_the_box_and_guide_the_chassis_round_it(seen):
    controller = build_controller(seen, seed=0, threads=2)
    episode = build_episode(seen, seed=0)
    try:
        controller.begin("lockstep", episode.dt)
        play(controller, episode, 3)
        field = controller.motion.problem.field_source.latest()
        assert field is not None and field.dims == 2
        points = torch.tensor(
            [
                [0.85, 1.28],  # the box's face towards the robot: seen
                [0.0, 0.0],  # the chassis' centre: neither its arm nor the cubes are seen
                [1.15 - 0.5, -0.3],  # half a metre before table A's face: declared and seen
            ],
            dtype=field.values.dtype,
        )
        d = field.lookup(points)
        assert d[0] < 0.1
        assert d[1] > 1.0
        assert abs(float(d[2]) - 0.5) < 0.1
        points = controller.guide.state.points
        assert points is not None
        dense = resample(points, 0.02)
        clear = signed_distance([BOX], dense).min()
        assert clear > GUIDE_RADIUS  # the chassis' way round the box, with room for it
        beside = dense[np.abs(dense[:, 1] - BOX.centre[1]) < BOX.half[1]]  # [K, 2]
        assert len(beside) and (beside[:, 0] < BOX.centre[0] - BOX.half[0] - GUIDE_RADIUS).all()
        assert math.dist(points[-1], STAND) < 0.1  # back on the base's line, off table B
    finally:
        controller.close()
        episode.close()


@pytest.mark.parametrize(
    "guide, message",
    [
        ({"room": "push"}, "guide.room: is for an object the robot moves"),
        ({"for": "box"}, "guide.for: not the robot or a free object"),
        ({"for": "table_b"}, "guide.for: not the robot or a free object"),
    ],
)
def test_a_guide_for_the_base_takes_no_room_and_no_perceived_or_fixed_object(seen, guide, message):
    with pytest.raises(ConfigError, match=message):
        parse_scenario(_with_guide(seen, guide), "seen.yaml")


def test_a_guide_for_a_name_the_planners_model_lacks_is_refused_when_it_is_built(seen):
    scenario = parse_scenario(_with_guide(seen, {"for": "chasis"}), "seen.yaml")
    with pytest.raises(ConfigError, match=r"guide\.for.*chasis.*chassis"):
        build_problem(scenario)


def _with_guide(seen, guide: dict) -> dict:
    """The scenario's raw YAML with ``guide`` over its guide's keys."""
    raw = {**seen.raw, "guide": {**seen.raw["guide"], **guide}}
    raw.pop("base", None)
    return raw
