"""Objects of every kind unknown to the planner (``world.objects[].perceived``): a free one is
simulated by the world, absent from the planner's model, and nothing of it but the scans
reaches the planner, while the episode log, its replay and its metrics keep the whole world; a
name the task needs may not be one. The episode's contacts with the perceived objects and its
closest approach to them (server/evaluation/clearance.py) against hand computations, and the
bench's table, which shows them only where they were measured."""

from __future__ import annotations

from types import SimpleNamespace

import mujoco
import numpy as np
import pytest
import yaml

from m3p2i.bench_report import HEADERS, PERCEIVED_HEADERS, markdown_report, summarize, table_rows
from m3p2i.bridge_layout import bridge_layout
from planner_client.build import build_controller
from planner_client.model_state import StateSizes
from planner_client.planner_check import scenario_errors as planner_errors
from planner_client.problem import build_problem
from server.episode import Episode, Published
from server.episode_log import read_log
from server.evaluation.clearance import DIST_MAX
from server.evaluation.metrics import MetricsEvaluator
from server.interface import WorldState
from server.world_check import scenario_errors as world_errors
from shared.config import ConfigError
from shared.scenario import load_scenario, parse_scenario
from shared.scene import compile_model

CRATE = {"pos": [1.2, 0.6, 0.15], "size": [0.2, 0.3, 0.15], "yaw": 20.0}
FIELDS = ("qpos", "qvel", "act", "mocap_pos", "mocap_quat")


def scene(crate=CRATE, objects=(), **extra) -> dict:
    """A point robot, a known free cube before and a known free ball after a free perceived
    crate (so that the crate's joint sits between theirs in the world's qpos), a fixed
    perceived box, and a lidar that sees both."""
    return {
        "name": "crate",
        "robot": {"model": "point_robot", "qpos": [0.0, 0.0]},
        "world": {
            "timestep": 0.05,
            "arena": {"half_size": 3.0},
            "objects": [
                {"name": "cube", "shape": "box", "size": [0.1, 0.1, 0.1]}
                | {"pos": [0.5, -1.5, 0.1], "fixed": False},
                {"name": "crate", "shape": "box", "fixed": False, "perceived": True, **crate},
                {"name": "box", "shape": "box", "size": [0.2, 0.2, 0.2]}
                | {"pos": [-1.2, 1.0, 0.2], "perceived": True},
                {"name": "ball", "shape": "sphere", "size": [0.1], "pos": [-1.5, -1.5, 0.1]}
                | {"fixed": False},
                {"name": "goal", "shape": "cylinder", "size": [0.2, 0.01]}
                | {"pos": [2.0, 2.0, 0.01], "visual": True},
                *objects,
            ],
        },
        "sensors": [{"name": "lidar", "type": "lidar", "pos": [0, 0, 0.27], "rays": 90}],
        "episode": {
            "max_time": 5.0,
            "success": [{"near": {"a": "robot", "b": "goal", "within": 0.1}}],
        },
        "objectives": {
            "go": {"terms": [{"term": "distance", "a": "robot", "b": "goal", "weight": 1.0}]}
        },
        "modes": ["go"],
        **extra,
    }


def load(tmp_path, raw: dict, name: str = "crate.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw))
    return load_scenario(path), path


def run(scenario, log, controls) -> list:
    """The states a scripted episode publishes, one per control, then its end."""
    episode = Episode(scenario, 0, log)
    states = [episode.publish()]
    for ctrl in controls:
        episode.apply(np.asarray(ctrl, float))
        states.append(episode.publish())
    episode.finish()
    return states


# ---------------------------------------------------------------- nothing of it reaches the planner


def test_a_free_perceived_object_is_the_worlds_alone_and_only_scans_show_it(tmp_path):
    here, _ = load(tmp_path, scene(), "here.yaml")
    moved = CRATE | {"pos": [1.6, -0.4, 0.2], "size": [0.3, 0.15, 0.2], "yaw": -35.0}
    there, _ = load(tmp_path, scene(crate=moved), "there.yaml")
    world = compile_model(here)
    models = [build_problem(sc).model for sc in (here, there)]
    for model in models:
        for kind in (mujoco.mjtObj.mjOBJ_GEOM, mujoco.mjtObj.mjOBJ_BODY):
            assert mujoco.mj_name2id(model, kind, "crate") == -1
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "crate_free") == -1
        assert (model.nq, model.nv, model.nmocap) == (world.nq - 7, world.nv - 6, world.nmocap - 1)
    for name in ("geom_size", "geom_pos", "body_pos", "body_quat", "qpos0"):
        assert np.array_equal(getattr(models[0], name), getattr(models[1], name)), name

    controls = [(1.0, 0.6)] * 10 + [(-0.5, 1.0)] * 10
    runs = [run(sc, tmp_path / f"{i}.jsonl", controls) for i, sc in enumerate((here, there))]
    for a, b in zip(*runs):
        for name in FIELDS:
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert any(not np.array_equal(a.scans[0].ranges, b.scans[0].ranges) for a, b in zip(*runs))
    assert [s.name for a in runs[0] for s in a.scans] and runs[0][0].scans  # scans did travel

    # the state is the planner's layout, which m3p2i layout prints, and the cube and the ball
    # on either side of the crate are where the planner's model has them
    state, layout = runs[0][-1], bridge_layout(here)
    sizes = StateSizes.of(models[0])
    assert layout.sizes == sizes and sizes.mismatches(vars(state)) == []
    assert set(layout.perceived) == {"crate", "box"}
    assert "crate" not in {c.body for c in layout.qpos}
    data = mujoco.MjData(models[0])
    data.qpos[:] = state.qpos
    mujoco.mj_kinematics(models[0], data)
    logged = read_log(tmp_path / "0.jsonl")
    last = logged[-2]  # the last step, before the summary
    full = mujoco.MjData(world)
    full.qpos[:] = last["qpos"]
    mujoco.mj_kinematics(world, full)
    for body in ("robot", "cube", "ball"):
        assert np.allclose(data.xpos[models[0].body(body).id], full.xpos[world.body(body).id])

    controller = build_controller(here, threads=2)
    try:
        controller.begin("lockstep", 0.05)
        assert controller.step(state).ctrl.shape == (2,)  # the state fits the planner's model
    finally:
        controller.close()


def test_the_log_keeps_the_whole_world_for_replay_and_metrics(tmp_path):
    sc, _ = load(tmp_path, scene())
    world = compile_model(sc)
    run(sc, tmp_path / "log.jsonl", [(0.5, 0.2)] * 5)
    records = read_log(tmp_path / "log.jsonl")
    assert records[0]["nq"] == world.nq
    steps = [r for r in records if r["kind"] == "step"]
    assert all(len(s["qpos"]) == world.nq and len(s["qvel"]) == world.nv for s in steps)
    crate = world.joint("crate_free").qposadr[0]
    assert np.allclose(steps[-1]["qpos"][crate : crate + 2], CRATE["pos"][:2], atol=1e-3)
    logged = records[-1]["metrics"]
    assert MetricsEvaluator(sc, world).evaluate(records).as_dict() == logged
    assert logged["perceived_contacts"] == 0 and 0 < logged["perceived_clearance_min"] < DIST_MAX


def test_a_view_puts_the_rows_back_and_keeps_the_perceived_objects_where_the_file_has_them(
    tmp_path,
):
    sc, _ = load(tmp_path, scene())
    world = compile_model(sc)
    rows = Published.of(sc, world)
    moved = mujoco.MjData(world)
    moved.qpos[:] = np.arange(world.nq) + 1.0
    moved.mocap_pos[:] = -np.arange(3 * world.nmocap).reshape(-1, 3)
    arrays = {name: getattr(moved, name).copy() for name in FIELDS}
    sent = rows.of_state(WorldState(time=0.0, **arrays))  # as the world sends it
    state = SimpleNamespace(**sent, act=arrays["act"])
    filed = mujoco.MjData(world)  # where the file puts everything
    back = rows.into(filed, state)
    crate = world.joint("crate_free").qposadr[0]
    hidden = np.zeros(world.nq, bool)
    hidden[crate : crate + 7] = True
    assert np.array_equal(back["qpos"][~hidden], moved.qpos[~hidden])
    assert np.array_equal(back["qpos"][hidden], filed.qpos[hidden])
    box = world.body("box").mocapid[0]
    assert np.array_equal(back["mocap_pos"][box], filed.mocap_pos[box])
    others = np.arange(world.nmocap) != box
    assert np.array_equal(back["mocap_pos"][others], moved.mocap_pos[others])


def test_rows_published_are_every_row_without_perceived_objects(tmp_path):
    raw = scene()
    for o in raw["world"]["objects"]:
        o.pop("perceived", None)
    sc, _ = load(tmp_path, raw)
    assert Published.of(sc, compile_model(sc)) is None  # the state is the world's, as before
    metrics = MetricsEvaluator(sc).evaluate([]).as_dict()
    assert "perceived_contacts" not in metrics and "perceived_clearance_min" not in metrics


# ---------------------------------------------------------------- what the task needs is known


def test_a_task_that_needs_a_free_perceived_object_is_refused_naming_the_key(tmp_path):
    raw = scene()
    raw["episode"]["success"] = [{"near": {"a": "robot", "b": "crate", "within": 0.3}}]
    _, path = load(tmp_path, raw)
    errors = [str(e) for e in world_errors(path)]
    assert any("episode.success[0].near.b" in e and "free perceived" in e for e in errors), errors

    raw = scene(
        task={
            "factors": {
                "isAt": {
                    "states": ["there", "not_there"],
                    "actions": {"move_to": {"effect": {"set": "there"}}},
                }
            },
            "goals": {"isAt": "there"},
        },
        observers={"isAt": {"near": {"a": "robot", "b": "crate", "within": 0.3}}},
        plan={"move_to": "go"},
    )
    raw.pop("modes")
    _, path = load(tmp_path, raw, "observed.yaml")
    errors = [str(e) for e in planner_errors(path)]
    assert any("observers.isAt" in e and "'crate'" in e for e in errors), errors

    raw = scene(planner={"model": {"objects": {"crate": {"planar": True}}}})
    with pytest.raises(ConfigError, match=r"planner\.model\.objects\.crate: not a free object"):
        parse_scenario(raw, str(tmp_path / "modelled.yaml"))
    visual = {"name": "ghost", "shape": "sphere", "size": [0.1], "pos": [0, 2, 0.1]}
    with pytest.raises(ConfigError, match=r"world\.objects\[5\]\.perceived: a visual object"):
        parse_scenario(scene(objects=[visual | {"visual": True, "perceived": True}]), "v.yaml")


# ---------------------------------------------------------------- contacts and closest approach

WALL = {"name": "wall", "shape": "box", "size": [0.2, 0.5, 0.2], "pos": [1.0, 0.0, 0.2]}
ROBOT_RADIUS = 0.2  # point_robot's disc


def clearance_scene(objects) -> dict:
    """The robot at the origin, a perceived wall whose face is at x = 0.8, a known post it may
    touch behind it (not counted) and what else ``objects`` adds."""
    post = {"name": "post", "shape": "cylinder", "size": [0.1, 0.2], "pos": [-0.4, 0.0, 0.2]}
    return {
        "name": "clearance",
        "robot": {"model": "point_robot", "qpos": [0.0, 0.0]},
        "world": {
            "timestep": 0.05,
            "objects": [WALL | {"perceived": True}, post, *objects],
        },
        "episode": {
            "max_time": 10.0,
            "success": [{"near": {"a": "robot", "b": "post", "within": 0.1}}],
        },
        "objectives": {"idle": {"terms": [{"term": "control_effort"}]}},
        "modes": ["idle"],
    }


def scripted(tmp_path, objects, controls) -> tuple[dict, list[dict]]:
    sc, _ = load(tmp_path, clearance_scene(objects), "clearance.yaml")
    run(sc, tmp_path / "drive.jsonl", controls)
    records = read_log(tmp_path / "drive.jsonl")
    return records[-1]["metrics"], [r for r in records if r["kind"] == "step"]


def test_driving_into_a_perceived_wall_twice_counts_two_contacts(tmp_path):
    # 1 m/s for 2 s reaches the face (x = 0.6 for the disc) and presses on; back off 1 s; again
    push, back = [(1.0, 0.0)] * 40, [(-1.0, 0.0)] * 20
    metrics, steps = scripted(tmp_path, [], push + back + push)
    assert max(s["qpos"][0] for s in steps) > 0.6 - 0.01
    assert metrics["perceived_contacts"] == 2
    assert metrics["perceived_clearance_min"] <= 0.0


def test_staying_away_counts_none_and_the_closest_approach_is_the_hand_computed_one(tmp_path):
    # a slow approach and back off the post (a known obstacle: touching it counts for nothing)
    controls = [(0.5, 0.0)] * 15 + [(-1.0, 0.0)] * 20
    metrics, steps = scripted(tmp_path, [], controls)
    face = WALL["pos"][0] - WALL["size"][0]
    want = min(face - ROBOT_RADIUS - s["qpos"][0] for s in steps)  # y stays 0: along x
    assert 0.05 < want < 0.5 and min(s["qpos"][0] for s in steps) < -0.4 + 0.1 + 0.2
    assert metrics["perceived_contacts"] == 0
    assert metrics["perceived_clearance_min"] == pytest.approx(want, abs=1e-6)


def test_a_known_free_object_counts_and_so_does_a_free_perceived_one(tmp_path):
    # a cube 5 cm off the wall's side; far off, a free perceived crate the robot drives into
    cube = {"name": "cube", "shape": "box", "size": [0.1, 0.1, 0.1], "fixed": False}
    crate = {"name": "crate", "shape": "box", "size": [0.2, 0.2, 0.2], "fixed": False}
    objects = [
        cube | {"pos": [1.0, 0.65, 0.1]},
        crate | {"pos": [0.0, -2.0, 0.2], "perceived": True},
    ]
    metrics, _ = scripted(tmp_path, objects, [(0.0, 0.0)] * 5)
    assert metrics["perceived_contacts"] == 0
    assert metrics["perceived_clearance_min"] == pytest.approx(0.05, abs=1e-6)
    metrics, _ = scripted(tmp_path, objects, [(0.0, -1.0)] * 50)  # the crate: 1.6 m away
    assert metrics["perceived_contacts"] >= 1 and metrics["perceived_clearance_min"] <= 0.0


# ---------------------------------------------------------------- the bench's table


def rows(case: str, contacts: str = "", clearance: str = "") -> list[dict[str, str]]:
    base = {"variant": "v", "reason": "", "success": "1", "position_error": "0.1"}
    base |= {"orientation_error": "", "collisions": "", "time": "3.0", "planner_hz": "20"}
    return [
        base
        | {"case": case, "seed": str(s), "perceived_contacts": contacts}
        | {"perceived_clearance_min": clearance and str(float(clearance) + s)}
        for s in range(2)
    ]


def test_the_perceived_columns_appear_where_a_case_measured_them():
    plain = summarize(rows("plain"), ["plain"])
    assert [len(r) for r in table_rows(plain, {})] == [len(HEADERS)]
    assert "perceived" not in markdown_report(table_rows(plain, {}), [], "# t")
    seen = summarize(rows("plain") + rows("seen", "0", "0.25"), ["plain", "seen"])
    table = table_rows(seen, {})
    assert [len(r) for r in table] == [len(HEADERS) + len(PERCEIVED_HEADERS)] * 2
    assert table[0][-2:] == ["—", "—"]
    assert table[1][-2:] == ["0.0000 (0.0000)", "0.7500 (0.5000), min 0.2500"]
    text = markdown_report(table, [], "# t")
    assert all(h in text for h in PERCEIVED_HEADERS) and "Perceived contacts:" in text
