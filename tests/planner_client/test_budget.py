"""The anytime planner's budget (planner_client/budget.py): it sheds samples when iterations
overrun the budget, never below the floor, then horizon steps, and takes them back (steps first)
when there is room."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from m3p2i.plots import budget_series, episode_series, plot_episode
from m3p2i.view.drawing import PanelInfo
from planner_client.budget import BudgetConfig, SampleBudget, budget_config
from planner_client.build import build_controller
from server.evaluation.log_reader import read_log, steps
from server.inprocess import build_episode, run_episode
from shared.config import ConfigError
from shared.scenario import load_scenario


def _machine(per_sample: float, fixed: float = 0.0):
    """An iteration's seconds on a machine: a fixed part and a part per sample (of 10 steps)."""
    return lambda n, steps=10: fixed + per_sample * n * steps / 10


def _budget(full=200, horizon=10, **cfg) -> SampleBudget:
    cfg = {"rate": 20.0, "min_samples": 40, "min_horizon": horizon, **cfg}
    return SampleBudget(BudgetConfig(**cfg), full=full, horizon=horizon)


def test_an_overrun_sheds_samples_to_what_fits_and_no_further_than_the_floor():
    budget = _budget()
    slow = _machine(0.5e-3)  # 200 samples: 100 ms, twice the 50 ms budget
    change = budget.observe(slow(budget.samples))
    assert change is not None and change.before == 200 and change.after < 100
    assert "over the budget of 50 ms" in change.reason
    for _ in range(20):
        budget.observe(slow(budget.samples))
    assert slow(budget.samples) <= 0.05 and budget.samples >= 40
    crawl = _machine(5e-3)  # even the floor overruns: it stays at the floor
    for _ in range(20):
        budget.observe(crawl(budget.samples))
    assert budget.samples == 40


def test_samples_come_back_when_the_machine_is_free_again_but_not_at_once():
    budget = _budget(patience=5)
    for _ in range(10):
        budget.observe(_machine(0.5e-3)(budget.samples))
    shed = budget.samples
    fast = _machine(0.05e-3)
    changes = [budget.observe(fast(budget.samples)) for _ in range(4)]
    assert changes == [None] * 4 and budget.samples == shed  # patience: not yet
    for _ in range(400):
        budget.observe(fast(budget.samples))
    assert budget.samples == 200  # all back, never above the full count


def test_a_machine_within_the_budget_keeps_every_sample():
    budget = _budget()
    assert all(budget.observe(0.03) is None for _ in range(50))
    assert budget.samples == 200
    assert budget.observe(float("nan")) is None and budget.observe(0.0) is None


def test_at_the_fewest_samples_it_sheds_steps_then_takes_them_back_first():
    budget = _budget(horizon=10, min_horizon=6, patience=2)
    crawl = _machine(2e-3)  # 40 samples x 10 steps: 80 ms, over the 50 ms budget
    changes = [budget.observe(crawl(budget.samples, budget.horizon)) for _ in range(40)]
    changes = [c for c in changes if c is not None]
    whats = [c.what for c in changes]
    assert whats[0] == "samples" and "horizon" in whats
    assert whats.index("horizon") > max(i for i, w in enumerate(whats) if w == "samples")
    assert budget.samples == 40 and budget.horizon == 6  # the floors, no further
    assert "at the fewest samples" in changes[-1].reason
    fast = _machine(0.02e-3)
    back = [budget.observe(fast(budget.samples, budget.horizon)) for _ in range(400)]
    back = [c.what for c in back if c is not None]
    assert back[: 10 - 6] == ["horizon"] * 4  # the steps first, one at a time
    assert budget.horizon == 10 and budget.samples == 200


def test_the_mppi_keeps_its_plans_first_steps_when_the_horizon_changes():
    controller = build_controller(load_scenario("navigation"), seed=0, threads=2)
    mppi = controller.motion.mppi
    try:
        mppi.update(mppi.sample().sum(-1) ** 2)  # one iteration: a plan to keep
        plan = mppi.nominal.clone()  # [5, nu]
        controller.motion.set_horizon(8)  # grown: the last step held
        assert mppi.horizon == 8 and mppi.sample().shape[1] == 8
        assert torch.equal(mppi.nominal[:5], plan)
        assert torch.equal(mppi.nominal[5:], plan[4:5].expand(3, -1))
        controller.motion.set_horizon(6)  # cut: the first steps kept
        assert torch.equal(mppi.nominal, torch.cat([plan, plan[4:5]]))
        with pytest.raises(ValueError, match="savgol_window"):  # shorter than the smoothing
            controller.motion.set_horizon(3)
        result = mppi.update(mppi.sample().sum(-1) ** 2)
        assert result.U.shape[0] == 6 and mppi.horizon == 6
    finally:
        controller.close()


def _with_budget(name: str, budget: dict, **planner):
    sc = load_scenario(name)
    return dataclasses.replace(
        sc, planner=dataclasses.replace(sc.planner, budget=budget, **planner)
    )


def test_a_controller_over_its_budget_sheds_samples_and_keeps_planning():
    # a budget no machine meets (10 µs an iteration): every iteration sheds, down to the floors
    sc = _with_budget("navigation", {"rate": 1e5, "min_samples": 40, "min_horizon": 6}, horizon=10)
    controller = build_controller(sc, seed=0, threads=2)
    episode = build_episode(sc, seed=0)
    try:
        controller.begin("realtime", episode.dt)  # stepped by hand: the world waits here
        state = episode.publish()
        for _ in range(30):
            command = controller.step(state)
            assert command is not None and command.plan_ctrl is not None  # still plans
            episode.play(command)
            state = episode.publish()
        changes = controller.stats.budget_changes
        assert changes and all(after < before for _, _, before, after, _ in changes)
        assert controller.motion.samples == 40 == controller.motion.mppi.num_samples
        assert command.samples == 40 and "over the budget" in changes[0][4]
        # then steps, down to min_horizon: the plan sent is that long
        assert controller.motion.horizon == 6 == len(command.plan_ctrl)
        assert [c[1] for c in changes][-1] == "horizon"
        controller.begin("realtime", episode.dt, seed=1, new_episode=True)
        assert controller.motion.samples == sc.planner.samples  # a new episode: all back
        assert controller.motion.horizon == sc.planner.horizon
        controller.begin("lockstep", episode.dt)  # the world waits: no budget, every sample
        assert controller.budget is None and controller.motion.samples == sc.planner.samples
        assert controller.step(episode.publish()).samples is None
    finally:
        controller.close()
        episode.close()


def test_a_lockstep_episode_with_a_budget_is_the_one_without(tmp_path):
    sc = _with_budget("navigation", {"rate": 1e5, "min_samples": 40})
    runs = [
        run_episode(s, build_controller, seed=0, log_path=tmp_path / f"{i}.jsonl")
        for i, s in enumerate((load_scenario("navigation"), sc))
    ]
    qpos = [[r["qpos"] for r in steps(read_log(run.log_path))] for run in runs]
    assert qpos[0] == qpos[1] and all("samples" not in r for r in steps(read_log(runs[1].log_path)))


def test_the_world_logs_the_samples_and_the_plot_draws_them(tmp_path):
    sc = load_scenario("navigation")
    controller = build_controller(sc, seed=0, threads=2)
    episode = build_episode(sc, seed=0, log_path=tmp_path / "episode.jsonl")
    try:
        controller.begin("lockstep", episode.dt)
        state = episode.publish()
        for n in (200, 150, 150, 90):  # as an anytime planner's commands carry them
            episode.play(dataclasses.replace(controller.step(state), samples=n))
            state = episode.publish()
    finally:
        controller.close()
        episode.close()
    records = read_log(tmp_path / "episode.jsonl")
    # a lock-step world notes a command's samples after its step, as its action, and the steps
    # of its plan beside them
    assert [r.get("samples") for r in steps(records)] == [None, 200, 150, 150]
    assert [r.get("horizon") for r in steps(records)] == [None] + [sc.planner.horizon] * 3
    series = episode_series(sc, records)
    assert series.samples is not None and np.nanmin(series.samples) == 150
    assert np.nanmin(series.horizon) == sc.planner.horizon
    assert plot_episode(series, tmp_path / "plot.png").stat().st_size > 0
    assert budget_series([{"time": 0.0}], "samples") is None  # no budget: no panel


@pytest.mark.parametrize(
    "budget, key",
    [
        ({"min_samples": 40}, r"planner\.budget\.rate"),
        ({"rate": 0}, r"planner\.budget\.rate"),
        ({"rate": 20, "min_samples": 2}, r"planner\.budget\.min_samples.*\[3, planner"),
        ({"rate": 20, "min_samples": 201}, r"planner\.budget\.min_samples"),
        ({"rate": 20, "patience": 0}, r"planner\.budget\.patience"),
        ({"rate": 20, "min_horizon": 4}, r"planner\.budget\.min_horizon.*\[5, planner"),
        ({"rate": 20, "rat": 1}, r"planner\.budget\.rat"),
    ],
)
def test_a_faulty_budget_is_refused_naming_its_key(budget, key):
    with pytest.raises(ConfigError, match=key):
        budget_config(_with_budget("navigation", budget))


def test_the_view_panel_shows_the_samples_under_a_budget():
    info = PanelInfo(scenario="navigation", planner_hz=20.0, plan_ms=48.0, samples=120, horizon=4)
    assert "20.0 Hz, 48 ms per plan, 120 samples per mode, 4 steps" in info.markdown()
    assert "samples per mode" not in PanelInfo(planner_hz=20.0).markdown()


@pytest.mark.parametrize("off", [None, {}])
def test_null_or_an_empty_mapping_switches_a_base_scenarios_budget_off(off):
    from m3p2i.sweep import apply_overrides
    from shared.scenario.reader import parse_scenario

    base = load_scenario("pick_place")
    assert budget_config(base) is not None  # the shipped one keeps 30 plans a second
    off = parse_scenario(apply_overrides(base.raw, {"planner.budget": off}), "test")
    assert budget_config(off) is None
    with pytest.raises(ConfigError, match=r"planner\.budget.*not a mapping"):
        parse_scenario(apply_overrides(base.raw, {"planner.budget": [30]}), "test")
