"""planner.tracking: the mirror filters noisy object poses and estimates the velocities a world
does not send (finite differences of the filtered poses); a teleport restarts the filters.
Synthetic states of the push scene's box (no physics): deterministic, with a seeded noise."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import yaml

from planner_client.mirror import Mirror
from planner_client.problem import build_problem
from shared import protocol as P
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, TrackingConfig, load_scenario, parse_scenario
from shared.scene import initial_data

V, W, DT = np.array([0.3, -0.2, 0.0]), 0.5, 0.05  # the box: m/s, rad/s about z, s per state


@pytest.fixture(scope="module")
def push():
    sc = load_scenario("push")
    model = build_problem(sc).model
    box = next(j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE)
    return model, initial_data(sc, model), model.jnt_qposadr[box], model.jnt_dofadr[box]


def _states(push, seconds: float, noise: float, seed: int = 0):
    """The box moving at V and turning at W, its velocities withheld (zeros), its position
    measured with ``noise`` (m, std)."""
    model, data, qa, _ = push
    rng = np.random.default_rng(seed)
    p0 = data.qpos[qa : qa + 3].copy()
    for k in range(int(seconds / DT)):
        t = k * DT
        qpos = data.qpos.copy()
        qpos[qa : qa + 3] = p0 + V * t + rng.normal(0.0, noise, 3)
        qpos[qa + 3 : qa + 7] = [np.cos(W * t / 2), 0.0, 0.0, np.sin(W * t / 2)]
        yield P.State(
            session="s",
            seq=k,
            time=t,
            qpos=qpos,
            qvel=np.zeros(model.nv),
            act=data.act.copy(),
            mocap_pos=data.mocap_pos.copy(),
            mocap_quat=data.mocap_quat.copy(),
        )


def _run(push, cfg, seconds=3.0, noise=0.005):
    model, _, qa, va = push
    mirror = Mirror(model, tracking=cfg)
    out = []
    for state in _states(push, seconds, noise):
        mirror.apply(state)
        out.append(
            (state.time, mirror.data.qvel[va : va + 6].copy(), mirror.data.qpos[qa : qa + 3].copy())
        )
    return out


def test_velocities_withheld_by_the_world_are_estimated_from_the_poses(push):
    cfg = TrackingConfig(object_velocities="from_poses", pose_filter=0.5, velocity_filter=0.3)
    late = [(v, p) for t, v, p in _run(push, cfg) if t >= 1.0]
    lin = np.array([v[:3] for v, _ in late])
    ang = np.array([v[3:] for v, _ in late])
    # 5 mm of noise makes a raw difference over 0.05 s off by ~0.14 m/s; filtered, the mean is
    # within 3 cm/s of the truth and one estimate within 15 cm/s
    assert np.linalg.norm(lin.mean(0) - V) < 0.03 and np.abs(lin - V).max() < 0.15
    np.testing.assert_allclose(ang.mean(0), [0.0, 0.0, W], atol=0.02)


def test_filtered_poses_are_closer_to_the_truth_than_the_measured_ones(push):
    _, data, qa, _ = push
    p0 = data.qpos[qa : qa + 3]
    w = 0.3
    filtered = _run(push, TrackingConfig(pose_filter=w, object_velocities="from_poses"))
    measured = _run(push, TrackingConfig(velocity_filter=0.999))  # active, poses unfiltered

    def error(run, lag=0.0):
        return np.mean([np.linalg.norm(p - (p0 + V * (t - lag))) for t, _, p in run[20:]])

    # an exponential filter lags a moving box by (1 - w) / w steps: compared with that lag, it
    # has less than half the measurement's error
    assert error(filtered, lag=(1 - w) / w * DT) < 0.5 * error(measured)


def test_a_predicting_filter_does_not_trail_a_box_moving_at_constant_velocity(push):
    _, data, qa, _ = push
    p0 = data.qpos[qa : qa + 3]
    cfg = TrackingConfig(pose_filter=0.35, velocity_filter=0.42, object_velocities="from_poses")

    def lag(cfg):  # mean error of the filtered position after 1 s, noise-free measurements
        run = _run(push, cfg, noise=0.0)
        return np.mean([np.linalg.norm(p - (p0 + V * t)) for t, _, p in run if t >= 1.0])

    # the exponential filter trails by (1 - w)/w states at the box's speed; the alpha-beta
    # filter converges onto the box
    trail = (1 - 0.35) / 0.35 * DT * np.linalg.norm(V)
    assert lag(cfg) == pytest.approx(trail, rel=0.05)
    assert lag(dataclasses.replace(cfg, predict=True)) < 0.02 * trail


def test_a_predicting_filter_still_filters_noise_and_turns(push):
    cfg = TrackingConfig(
        pose_filter=0.35, velocity_filter=0.42, object_velocities="from_poses", predict=True
    )
    late = [v for t, v, _ in _run(push, cfg, noise=0.005) if t >= 1.0]
    lin = np.array([v[:3] for v in late])
    ang = np.array([v[3:] for v in late])
    assert np.linalg.norm(lin.mean(0) - V) < 0.03 and np.abs(lin - V).max() < 0.2
    np.testing.assert_allclose(ang.mean(0), [0.0, 0.0, W], atol=0.02)


def test_received_velocities_pass_through_by_default(push):
    model, _, _, _va = push
    assert Mirror(model).estimator is None
    assert all(np.all(v == 0) for _, v, _ in _run(push, TrackingConfig(), seconds=0.5))


def test_a_teleport_restarts_the_filters(push):
    model, _data, qa, va = push
    mirror = Mirror(
        model,
        tracking=TrackingConfig(
            object_velocities="from_poses", pose_filter=0.5, velocity_filter=0.5
        ),
    )
    states = list(_states(push, 1.0, 0.0))
    for s in states:
        mirror.apply(s)
    jumped = states[-1].qpos.copy()
    jumped[qa] += 1.0  # 1 m in 0.05 s: 20 m/s
    last = states[-1]
    mirror.apply(
        P.State(
            session="s",
            seq=last.seq + 1,
            time=last.time + DT,
            qpos=jumped,
            qvel=last.qvel,
            act=last.act,
            mocap_pos=last.mocap_pos,
            mocap_quat=last.mocap_quat,
        )
    )
    assert np.all(mirror.data.qvel[va : va + 6] == 0)
    assert mirror.data.qpos[qa] == pytest.approx(jumped[qa])


@pytest.mark.parametrize(
    "key, value, expected",
    [
        ("object_velocities", "guessed", "one of: from_poses, received"),
        ("pose_filter", 0, "(0, 1]"),
        ("velocity_filter", 1.5, "(0, 1]"),
        ("max_speed", -1, "> 0"),
        ("still_speed", -0.1, ">= 0"),
        ("predict", "yes", "true or false"),
        ("filter", 0.5, "unknown key"),
    ],
)
def test_tracking_keys_are_checked(key, value, expected):
    raw = yaml.safe_load((SCENARIO_DIR / "push.yaml").read_text())
    raw["planner"]["tracking"] = {key: value}
    with pytest.raises(ConfigError, match=rf"planner\.tracking\.{key}") as info:
        parse_scenario(raw, "p.yaml")
    assert expected in str(info.value)


@pytest.fixture(scope="module")
def table():
    """pick_place's planning model: its table is a mocap body (a fixed object)."""
    sc = load_scenario("pick_place")
    model = build_problem(sc).model
    return model, initial_data(sc, model)


def _mocap_run(table, cfg, velocity=(0.0, 0.0, 0.0), seconds=3.0, noise=0.005, dt=0.01):
    """The table measured with ``noise`` (m, std) every ``dt`` s, moving at ``velocity``; the
    mirror's estimated mocap velocity after each state (from 0.5 s on)."""
    model, data = table
    rng = np.random.default_rng(1)
    mirror = Mirror(model, tracking=cfg)
    p0 = data.mocap_pos.copy()
    out = []
    for k in range(int(seconds / dt)):
        pos = p0 + np.asarray(velocity) * k * dt + rng.normal(0.0, noise, p0.shape)
        mirror.apply(
            P.State(
                session="s",
                seq=k,
                time=k * dt,
                qpos=data.qpos.copy(),
                qvel=np.zeros(model.nv),
                act=data.act.copy(),
                mocap_pos=pos,
                mocap_quat=data.mocap_quat.copy(),
            )
        )
        if k * dt >= 0.5:
            out.append(
                (
                    mirror.mocap().vel[0].copy(),
                    mirror.data.mocap_pos[0] - p0[0] - np.asarray(velocity) * k * dt,
                )
            )
    return out


def test_a_noisy_fixed_object_is_filtered_and_does_not_move(table):
    """A tracker's 5 mm noise on the table: raw differences read it moving at up to ~1 m/s (the
    rollouts then threw the table and the cube on it about); filtered, it stays put."""
    raw = np.array([v for v, _ in _mocap_run(table, TrackingConfig())])
    assert np.linalg.norm(raw, axis=1).max() > 0.8
    cfg = TrackingConfig(object_velocities="from_poses", pose_filter=0.15, velocity_filter=0.3)
    run = _mocap_run(table, cfg)
    speeds = np.array([np.linalg.norm(v) for v, _ in run])
    assert speeds.max() < 0.2 and np.median(speeds) < 0.06
    assert np.median([np.linalg.norm(e) for _, e in run]) < 0.004  # 5 mm measured
    still = _mocap_run(table, dataclasses.replace(cfg, still_speed=0.12))
    assert np.mean([not v.any() for v, _ in still]) > 0.99


def test_a_moving_fixed_object_keeps_its_velocity_above_still_speed(table):
    """A scripted obstacle at 0.3 m/s, 5 mm noisy: its velocity is estimated within 5 cm/s on
    average, and ``still_speed`` (0.12 m/s) does not stop it."""
    v = np.array([0.3, 0.0, 0.0])
    cfg = TrackingConfig(
        object_velocities="from_poses", pose_filter=0.15, velocity_filter=0.3, still_speed=0.12
    )
    vel = np.array([u for u, _ in _mocap_run(table, cfg, velocity=v)])
    assert np.linalg.norm(vel.mean(0) - v) < 0.05
    assert np.all(np.linalg.norm(vel, axis=1) > 0.12)


def test_still_speed_zeroes_a_resting_objects_velocity(push):
    """The box at rest under 5 mm of noise: with ``still_speed`` its estimated velocity is 0
    in nearly every state, without it never."""
    model, data, qa, va = push
    rng = np.random.default_rng(2)

    def run(cfg):
        mirror = Mirror(model, tracking=cfg)
        out = []
        for k in range(200):
            qpos = data.qpos.copy()
            qpos[qa : qa + 3] += rng.normal(0.0, 0.005, 3)
            mirror.apply(
                P.State(
                    session="s",
                    seq=k,
                    time=k * 0.01,
                    qpos=qpos,
                    qvel=np.zeros(model.nv),
                    act=data.act.copy(),
                    mocap_pos=data.mocap_pos.copy(),
                    mocap_quat=data.mocap_quat.copy(),
                )
            )
            out.append(not mirror.data.qvel[va : va + 6].any())
        return np.mean(out[50:])

    cfg = TrackingConfig(object_velocities="from_poses", pose_filter=0.15, velocity_filter=0.3)
    assert run(cfg) == 0.0
    assert run(dataclasses.replace(cfg, still_speed=0.12)) > 0.99


def test_a_state_with_the_same_time_stamp_is_a_duplicate_not_a_new_episode():
    from planner_client.tracking import PoseFilter

    cfg = TrackingConfig(pose_filter=0.5, velocity_filter=0.5)
    f = PoseFilter(1, cfg)
    quat = np.array([[1.0, 0.0, 0.0, 0.0]])
    for k in range(10):
        f(k * DT, np.array([[0.1 * k, 0.0, 0.0]]), quat)
    pos, vel = f.pos.copy(), f.vel.copy()
    assert vel[0, 0] > 0.5
    f(9 * DT, np.array([[0.93, 0.0, 0.0]]), quat)  # the last state again, re-measured
    np.testing.assert_array_equal(f.pos, pos)
    np.testing.assert_array_equal(f.vel, vel)
    f(0.0, np.array([[5.0, 0.0, 0.0]]), quat)  # time went back: a new episode
    np.testing.assert_array_equal(f.pos, [[5.0, 0.0, 0.0]])
    assert not f.vel.any()
