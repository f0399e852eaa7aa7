"""The control loop without the network: :class:`planner_client.controller.Controller` on single
states, and :mod:`server.inprocess` running whole episodes in one process, step for step
and bit for bit the episodes two processes run in lock-step."""

from __future__ import annotations

import dataclasses
from functools import partial

import numpy as np
import pytest

from planner_client.build import build_controller
from planner_client.controller import LayoutMismatch
from planner_client.task import TaskDecision
from server.evaluation.log_reader import read_log, steps, summary
from server.inprocess import run_episode
from shared import protocol as P
from shared.scenario import load_scenario
from tests.helpers import free_port_block, start_planner, start_server, stop, wait_episode


@pytest.fixture(scope="module")
def nav():
    return load_scenario("navigation")


@pytest.fixture
def controller(nav):
    controller = build_controller(nav, seed=0, threads=2)
    controller.begin("lockstep", nav.world.timestep)
    yield controller
    controller.close()


def _state(model, seq: int = 3, time: float = 0.15, **fields) -> P.State:
    return P.State(
        session="s",
        seq=seq,
        time=time,
        qpos=np.zeros(model.nq),
        qvel=np.zeros(model.nv),
        act=np.zeros(model.na),
        mocap_pos=np.zeros((model.nmocap, 3)),
        mocap_quat=np.tile([1.0, 0, 0, 0], (model.nmocap, 1)),
        **fields,
    )


def test_a_step_answers_the_state_with_a_plan_dated_at_its_time(controller, nav):
    model = controller.motion.problem.model
    cmd = controller.step(_state(model))
    assert (cmd.session, cmd.seq, cmd.action) == ("s", 3, "navigate")
    assert cmd.plan_t0 == 0.15 and cmd.plan_dt == controller.motion.dt  # lock-step: no lead
    assert cmd.plan_ctrl.shape == (nav.planner.horizon, model.nu)
    np.testing.assert_array_equal(cmd.ctrl, cmd.plan_ctrl[0])
    assert cmd.plan_time > 0 and controller.stats.iterations == 1
    assert controller.stats.action_changes == [(0.15, "navigate", ("navigate",))]
    diag = controller.diagnostics()  # made when asked, from the last step
    assert diag.seq == 3 and diag.mode_names == ["navigate"] and diag.top.shape[-1] == 3


def test_a_task_that_says_stop_gets_the_safe_stop_without_a_plan(controller):
    model = controller.motion.problem.model
    controller.task = type(
        "Done",
        (),
        {
            "decide": lambda self, data, extras, time: TaskDecision(
                action="done", modes=("navigate",), stop=True
            )
        },
    )()
    cmd = controller.step(_state(model))
    assert not cmd.has_plan and cmd.plan_t0 is None
    np.testing.assert_array_equal(cmd.ctrl, controller.robot.safe_stop())


def test_the_end_of_the_episode_and_a_wrong_layout_are_told(controller):
    model = controller.motion.problem.model
    assert not controller.over(_state(model))
    assert controller.over(_state(model, status="success"))
    assert controller.stats.final_status == "success"
    with pytest.raises(LayoutMismatch, match="qpos has 3 values"):
        controller.check_layout(dataclasses.replace(_state(model), qpos=np.zeros(model.nq + 1)))


def test_an_episode_in_process_stops_after_max_steps(tmp_path):
    seen = []
    result = run_episode(
        "navigation",
        partial(build_controller, threads=2),
        log_path=tmp_path / "e.jsonl",
        max_steps=3,
        on_step=lambda state, cmd: seen.append((state.seq, cmd.seq)),
    )
    assert result.status == "stopped" and result.summary["steps"] == 3
    assert seen == [(0, 0), (1, 1), (2, 2)]
    assert result.stats.iterations == 3 and result.stats.final_status == "stopped"
    assert [r["seq"] for r in steps(read_log(result.log_path))] == [1, 2, 3]


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["navigation", "pick_place"])
def test_an_episode_in_process_is_the_two_process_lockstep_episode(scenario, tmp_path):
    port = free_port_block()
    two = tmp_path / "two-process.jsonl"
    server = start_server(scenario, port, two, "--seed", "0")
    planner = start_planner(scenario, port, "--seed", "0")
    try:  # both run beside the in-process episode: lock-step does not depend on load
        one = run_episode(
            scenario, build_controller, seed=0, log_path=tmp_path / "in-process.jsonl"
        )
        out = wait_episode(server, planner, timeout=600)
        planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode == 0, out
    assert one.success, one.summary
    ours, theirs = steps(read_log(one.log_path)), steps(read_log(two))
    assert len(ours) == len(theirs) == one.summary["steps"]
    assert ours[-1]["time"] == theirs[-1]["time"]
    for key in ("qpos", "qvel", "ctrl", "action", "plan_seq", "age", "safe"):
        assert [s[key] for s in ours] == [s[key] for s in theirs], key  # bit for bit
    other = summary(read_log(two))
    assert other["status"] == one.summary["status"] == "success"
    assert other["measures"] == one.summary["measures"]
    assert other["actions"] == one.summary["actions"]
