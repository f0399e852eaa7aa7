"""The planner's lidar map wired into the control loop (planner_client/maps.py, issue 56): the
controller fuses each state's scans into a field that the ``perceived_clearance`` term and the
guide read, and navigation_seen, whose obstacles only its lidar shows, is planned round them."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import yaml

from planner_client.build import build_controller
from planner_client.global_path import Shape, signed_distance
from planner_client.planner_check import scenario_errors
from server.evaluation.log_reader import read_log, steps
from server.inprocess import build_episode, run_episode
from shared.config import ConfigError
from shared.scenario import find_scenario, load_scenario
from tests.helpers import play

PERCEIVED = ("block_a", "block_b", "pillar")
# navigation_seen's perceived obstacles as footprints, the robot disc's radius
FOOTPRINTS = [
    Shape("box", (-1.5, 1.5), (0.4, 0.4)),
    Shape("box", (-2.6, 1.8), (0.2, 0.8), math.radians(30)),
    Shape("disk", (0.8, -1.2), (0.3, 0.0)),
]
ROBOT_RADIUS = 0.2


@pytest.fixture(scope="module")
def seen():
    return load_scenario("navigation_seen")


def test_the_controller_fuses_the_lidar_into_the_field_the_cost_reads(seen):
    controller = build_controller(seen, seed=0, threads=2)
    episode = build_episode(seen, seed=0)
    try:
        controller.begin("lockstep", episode.dt)
        slot = controller.motion.problem.field_source
        assert slot.latest() is None  # no scan yet: no field
        play(controller, episode, 4)
        field = slot.latest()
        assert field is controller.map.latest()
        points = torch.tensor(
            [
                [-1.1, 1.5],  # block_a's face towards the robot
                [0.5, -1.2],  # the pillar's
                [1.5, 1.5],  # open floor, 2.5 m and more from anything
                [-3.95, 0.0],  # by the west wall: declared, composed into the field
            ],
            dtype=field.values.dtype,
        )
        d = field.lookup(points)
        assert d[0] < 0.1 and d[1] < 0.1
        assert d[2] > 1.5
        assert d[3] < 0.1
        stats = controller.map.stats()
        assert stats["fields"] >= 1 and stats["fused"] >= 1
    finally:
        controller.close()
        episode.close()
    assert slot.latest() is None  # closed: the slot empties
    assert controller.stats.map is not None and controller.stats.map["fields"] >= 1


def test_a_scenario_without_lidar_has_no_map():
    controller = build_controller("navigation", seed=0, threads=2)
    try:
        controller.begin("lockstep", 0.05)
        assert controller.map is None
        assert controller.motion.problem.field_source.latest() is None
    finally:
        controller.close()
    assert controller.stats.map is None


def test_a_real_time_world_gets_a_threaded_map_and_a_new_episode_a_new_one(seen):
    controller = build_controller(seen, seed=0, threads=2)
    try:
        controller.begin("realtime", 0.05)
        first = controller.map
        assert first is not None and first._thread is not None
        controller.begin("realtime", 0.05)  # a reconnection keeps what the map has seen
        assert controller.map is first
        controller.begin("lockstep", 0.05, seed=1, new_episode=True)
        assert controller.map is not first and controller.map._thread is None
        assert not first._thread.is_alive()
        assert controller.motion.problem.field_source._source is controller.map
    finally:
        controller.close()


def test_a_faulty_planner_map_is_refused_at_build(seen):
    bad = dataclasses.replace(
        seen, planner=dataclasses.replace(seen.planner, map={"resolution": 0.05, "rat": 10})
    )
    with pytest.raises(ConfigError, match=r"planner\.map\.rat"):
        build_controller(bad, seed=0, threads=2)


def test_navigation_seen_reaches_the_goal_round_obstacles_the_planner_lacks(seen, tmp_path):
    controller = None

    def planner(sc, seed):
        nonlocal controller
        controller = build_controller(sc, seed=seed, threads=2)
        return controller

    result = run_episode(seen, planner, seed=0, log_path=tmp_path / "episode.jsonl")
    assert result.status == "success"
    model = controller.motion.problem.model
    bodies = {model.body(i).name for i in range(model.nbody)}
    assert not bodies & set(PERCEIVED)  # the planner's model lacks them: only scans show them
    assert result.summary["metrics"]["collisions"] == 0
    qpos = np.array([r["qpos"][:2] for r in steps(read_log(result.log_path)) if r.get("qpos")])
    gap = signed_distance(FOOTPRINTS, qpos) - ROBOT_RADIUS
    assert gap.min() > 0.0


def test_m3p2i_check_names_a_bad_map_key(tmp_path):
    # the planner reads planner.map; its check (part of m3p2i check) reads it too
    raw = yaml.safe_load(find_scenario("navigation_seen").read_text())
    raw["base"] = "navigation"
    raw["planner"]["map"]["rat"] = 5
    path = tmp_path / "bad_map.yaml"
    path.write_text(yaml.safe_dump(raw))
    errors = [str(e) for e in scenario_errors(path)]
    assert errors == [
        f"{path}: planner.map.rat: unknown key"
        " (expected one of: box, dims, padding, rate, resolution)"
    ], errors
