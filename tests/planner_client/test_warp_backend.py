"""The MuJoCo Warp rollout backend (planner_client/backends/warp.py) on the CPU device.

Tests marked ``warp`` compile MJWarp's kernels (minutes on 2 cores the first time, seconds from
the cache in ~/.cache/warp) and are deselected by default: ``python -m pytest -m warp`` runs
them. The others need the m3p2i[gpu] extra but compile nothing.

Tolerances (float32 MJWarp against float64 MuJoCo, 15 steps, measured 2026-11-30): smooth motion
agrees to float32 rounding (positions within 1e-6 m, velocities 2e-6 m/s); where contacts decide
the motion the contact solver's float32 solution (tolerance raised to 1e-6 by MJWarp) is
amplified step by step: the box pushed in push_pull within 2e-4 m and 2e-4 in its quaternion,
navigation's contact force against a block within 1e-4 of its size (0.016 N of 269 N).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml

from planner_client.problem import build_problem
from shared.config import ConfigError
from shared.scenario import find_scenario, load_scenario
from tests.helpers import free_port_block, start_planner, start_server, stop

mjw = pytest.importorskip("mujoco_warp", reason="the m3p2i[gpu] extra is not installed")

from planner_client.backends.warp import WarpBackend  # noqa: E402
from planner_client.backends.warp_limits import check_warp, warp_limits  # noqa: E402


def _scenario_with(tmp_path, name: str, **planner) -> str:
    raw = yaml.safe_load(find_scenario(name).read_text())
    raw["planner"].update(planner)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


# -- start-up checks: no kernels compiled -----------------------------------------------------


@pytest.mark.parametrize("key, value", [("backend", "gpu"), ("device", "gpu0"), ("nconmax", 0)])
def test_planner_backend_keys_are_validated(tmp_path, key, value):
    with pytest.raises(ConfigError) as err:
        load_scenario(_scenario_with(tmp_path, "navigation", **{key: value}))
    assert f"planner.{key}" in str(err.value)


def test_backend_keys_load(tmp_path):
    sc = load_scenario(
        _scenario_with(tmp_path, "navigation", backend="warp", device="cpu", nconmax=32)
    )
    assert (sc.planner.backend, sc.planner.device, sc.planner.nconmax, sc.planner.njmax) == (
        "warp",
        "cpu",
        32,
        None,
    )
    assert load_scenario("navigation").planner.backend == "mujoco"


def test_limits_name_each_unsupported_feature():
    import mujoco

    model = build_problem(load_scenario("navigation")).model
    assert warp_limits(model) == []
    model.opt.solver = mujoco.mjtSolver.mjSOL_PGS
    model.actuator_gaintype[1] = mujoco.mjtGain.mjGAIN_PID
    problems = warp_limits(model)
    assert problems == [
        f"actuator {model.actuator(1).name!r} has gain mjGAIN_PID",
        "option solver mjSOL_PGS",
    ]
    with pytest.raises(ConfigError) as err:
        check_warp(model, "navigation.yaml")
    assert "planner.backend" in str(err.value) and "mjSOL_PGS" in str(err.value)


def test_adhesion_beside_distance_sensors_is_refused():
    """push_pull's suction next to robot-wall distance sensors: MJWarp 4.0.0 would weaken it."""
    problems = warp_limits(build_problem(load_scenario("push_pull")).model)
    assert len(problems) == 1
    assert (
        "actuator 'suction'" in problems[0] and "m3p2i__distance__robot__wall_north" in problems[0]
    )
    assert warp_limits(build_problem(load_scenario("push")).model) == []


def test_shipped_models_within_limits_are_accepted_by_mjwarp():
    """The check agrees with MJWarp's own put_model (which compiles nothing)."""
    for name in ("navigation", "pick_place"):
        model = build_problem(load_scenario(name)).model
        assert warp_limits(model) == []
        mjw.put_model(model)


def test_unknown_device_is_a_config_error():
    model = build_problem(load_scenario("navigation")).model
    with pytest.raises(ConfigError) as err:
        WarpBackend(model, device="cuda:7", source="navigation.yaml")
    assert "planner.device" in str(err.value) and "cuda:7" in str(err.value)


# -- rollouts on the CPU device: kernels compiled ---------------------------------------------

from planner_client.backends.mujoco_pool import MujocoPoolBackend  # noqa: E402
from tests.warp_cases import case, deviation  # noqa: E402


def _both(c, monkeypatch=None):
    cpu = MujocoPoolBackend(c.problem.model, 1)
    cpu.set_mocap(*c.mocap)
    ref = cpu.sensors(c.x0, torch.from_numpy(c.control)).numpy().copy()
    cpu.close()
    warp = WarpBackend(c.problem.model, device="cpu")
    warp.set_mocap(*c.mocap)
    got = warp.sensors(c.x0, torch.from_numpy(c.control))
    assert got.dtype == torch.float64 and got.shape == ref.shape
    return got.numpy(), ref


# (scenario, contact, {sensor kind: tolerance}); units: m, unit axis, N, rad, m/s
CASES = [
    ("navigation", False, {"framepos": 1e-6, "contactforce": 1e-6}),
    ("navigation", True, {"framepos": 1e-5, "contactforce": 0.1}),
    (
        "pick_place",
        False,
        {
            "framepos": 1e-5,
            "framexaxis": 1e-5,
            "frameyaxis": 1e-5,
            "framezaxis": 1e-5,
            "jointpos": 1e-5,
            "framelinvel": 1e-4,
            "distance": 1e-5,
            "contactforce": 1e-6,
        },
    ),
]


@pytest.mark.warp
@pytest.mark.parametrize(
    "scenario, contact, tol",
    CASES,
    ids=[f"{s}-{'contact' if c else 'smooth'}" for s, c, _ in CASES],
)
def test_warp_rollouts_match_mujoco_rollout(scenario, contact, tol):
    c = case(scenario, contact, samples=16)
    got, ref = _both(c)
    dev = deviation(c.problem, got, ref)
    assert set(dev) == set(tol)
    assert all(dev[k] <= tol[k] for k in tol), dev
    if contact:  # the case is what it claims: the robot pushes against block_a
        forces = [
            ref[..., cols]
            for r, cols in c.problem.columns.spans.items()
            if r.kind == "contactforce"
        ]
        assert max(float(np.abs(f).max()) for f in forces) > 10.0


@pytest.mark.warp
def test_warp_push_pull_rollouts_match_with_the_suction_off(monkeypatch):
    """The robot pushing the box (suction off): contact-rich, float32 amplified by contacts. With
    the suction on MJWarp differs (refused at start-up, see warp_limits), so this case passes the
    start-up check by hand."""
    monkeypatch.setattr("planner_client.backends.warp.check_warp", lambda *a, **k: None)
    c = case("push_pull", True, samples=16)
    c.control[..., 2] = 0.0  # suction off
    got, ref = _both(c)
    dev = deviation(c.problem, got, ref)
    # the box's axes in the robot's frame (the orientation cost): a unit axis moves by the angle.
    # float32 through contacts, MuJoCo and MJWarp 4.0.1: the axes part by up to 3.9e-3 (0.2°)
    # where the box's position stays within 6.5e-4 m (its 0.2 m half-width turned by 3e-3)
    axes = max(dev[k] for k in ("framexaxis", "frameyaxis", "framezaxis"))
    assert dev["framepos"] <= 1e-3 and axes <= 5e-3 and dev["distance"] <= 1e-5, dev
    box = c.problem.columns.spans[
        next(r for r in c.problem.columns.spans if r.kind == "framepos" and r.obj == "box")
    ]
    assert np.abs(ref[:, -1, box] - ref[:, 0, box]).max() > 0.05  # the box was pushed


@pytest.mark.warp
@pytest.mark.slow
def test_warp_navigation_episode_succeeds_on_cpu(tmp_path):
    """Lock-step navigation, both processes, the planner rolling out with MJWarp on the CPU."""
    from server.episode_log import read_log

    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log)
    planner = start_planner("navigation", port, "--backend", "warp", "--device", "cpu")
    try:
        out, _ = server.communicate(timeout=600)
        planner_out, _ = planner.communicate(timeout=60)
    finally:
        stop(server, planner)
    assert server.returncode == 0, out
    assert planner.returncode == 0, planner_out
    summary = read_log(log)[-1]
    assert summary["status"] == "success"
    assert summary["measures"]["distance robot-goal"] <= 0.1


def test_planner_check_reports_warp_limits(tmp_path):
    """m3p2i check / m3p2i-planner --check meet the limits before anything starts."""
    from planner_client.planner_check import scenario_errors

    errors = scenario_errors(_scenario_with(tmp_path, "push_pull", backend="warp", device="cpu"))
    assert [e.path for e in errors] == ["planner.backend"] and "suction" in str(errors[0])
    assert scenario_errors(_scenario_with(tmp_path, "navigation", backend="warp")) == []
