"""Time-indexed plans: the world plays them, the planner keeps time (docs/protocol.md, "Playing a
plan"; planner_client/timing.py)."""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np
import pytest
import torch
import yaml
import zmq

from planner_client.mppi import M3P2I, ModeSpec, MPPIConfig
from planner_client.mppi.shift import shift
from planner_client.timing import LeadEstimate, playing, predict, steps_between
from server.evaluation.log_reader import read_log
from server.evaluation.plan_ages import timing_summary
from server.plan_player import PlanPlayer
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from shared.scene import compile_model, reset_data
from shared.timed_plan import TimedPlan, held
from tests.helpers import free_port_block, start_server, stop

KNOTS = np.arange(10.0).reshape(5, 2)  # [H=5, nu=2]: knot i is (2i, 2i+1)


# ------------------------------------------------------------------ plans (pure)


def test_a_plan_holds_each_knot_for_its_interval_and_ends():
    plan = TimedPlan(t0=1.0, dt=0.03, ctrl=KNOTS)
    assert plan.at(0.99) is None  # before its time
    np.testing.assert_array_equal(plan.at(1.0), KNOTS[0])
    np.testing.assert_array_equal(plan.at(1.02), KNOTS[0])  # zero-order hold
    np.testing.assert_array_equal(plan.at(1.03), KNOTS[1])  # boundaries in float sums
    np.testing.assert_array_equal(plan.at(1.0 + 4 * 0.03), KNOTS[4])
    assert plan.at(plan.end) is None and math.isclose(plan.end, 1.15)


def test_the_player_queues_early_plans_and_starts_each_at_its_time():
    player = PlanPlayer()
    a = TimedPlan(0.0, 0.01, KNOTS, seq=0)
    b = TimedPlan(0.02, 0.01, KNOTS + 100, seq=1)
    c = TimedPlan(0.03, 0.01, KNOTS + 200, seq=2)
    player.receive(a)
    player.receive(b)
    player.receive(c)  # b must not be replaced by c before its time: that starved plans
    assert player.control(0.0)[1] is a and player.control(0.01)[1] is a
    ctrl, plan = player.control(0.02)
    assert plan is b and ctrl[0] == 100
    ctrl, plan = player.control(0.035)
    assert plan is c and ctrl[0] == 200
    assert player.control(0.08) == (None, c)  # ran out: the safe control
    player.receive(TimedPlan(0.05, 0.01, KNOTS, seq=3))  # late: starts at its knot
    np.testing.assert_array_equal(player.control(0.08)[0], KNOTS[3])


def test_a_command_without_a_plan_is_held_until_the_next():
    player = PlanPlayer()
    player.receive(held(np.array([1.0, 2.0]), 0.5, seq=7))
    np.testing.assert_array_equal(player.control(99.0)[0], [1.0, 2.0])
    assert player.control(99.0)[1].seq == 7


def test_what_the_planner_predicts_the_world_plays_is_what_the_player_plays():
    plans = [
        TimedPlan(0.0, 0.02, KNOTS, 0),
        TimedPlan(0.04, 0.02, KNOTS + 10, 1),
        TimedPlan(0.06, 0.02, KNOTS + 20, 2),
    ]
    player = PlanPlayer()
    for p in plans:
        player.receive(p)
    for t in np.arange(0.0, 0.2, 0.01):
        expect = player.control(float(t))[0]
        got = playing(plans, float(t))
        assert (got is None and expect is None) or np.array_equal(got, expect), t


# ------------------------------------------------------------------ the planner keeps time


def _cfg(**kw) -> MPPIConfig:
    return MPPIConfig(**{"horizon": 8, "nu": 2, "noise_sigma": (0.5, 0.5), "seed": 3, **kw})


def test_shift_moves_a_sequence_by_whole_and_fractional_steps():
    seq = torch.arange(8.0).reshape(1, 8, 1).expand(1, 8, 2)  # value = step index
    assert torch.equal(shift(seq), shift(seq, 1.0))
    assert shift(seq, 3)[0, :, 0].tolist() == [3, 4, 5, 6, 7, 7, 7, 7]
    assert shift(seq, 0.5)[0, :3, 0].tolist() == [0.5, 1.5, 2.5]
    assert shift(seq, -1)[0, :3, 0].tolist() == [0, 0, 1]  # earlier: hold the first


def test_an_iteration_that_took_three_steps_shifts_the_warm_start_by_three():
    planner = M3P2I(_cfg(), [ModeSpec("a", 16)])
    costs = torch.rand(16, 8, dtype=torch.float64)
    planner.sample()
    result = planner.update(costs)
    planner.advance(3)
    assert torch.allclose(planner.nominal[:5], result.U[3:], atol=1e-12)
    assert torch.equal(planner.nominal[5:], result.U[-1:].expand(3, 2))
    before = planner.nominal.clone()
    planner.advance(3)  # from the plan update() left, not from the last advance
    assert torch.equal(planner.nominal, before)


def test_advance_one_step_changes_nothing_so_lockstep_stays_exact():
    a, b = (M3P2I(_cfg(), [ModeSpec("a", 16)]) for _ in range(2))
    costs = torch.rand(16, 8, dtype=torch.float64)
    for p in (a, b):
        p.sample()
        p.update(costs)
    b.advance(steps_between(0.29, 0.30, 0.01))  # float times: 1.0000000000000009 steps
    assert torch.equal(a.nominal, b.nominal) and torch.equal(a.means, b.means)


def test_the_lead_is_the_largest_recent_lag_in_whole_world_steps():
    lead = LeadEstimate(world_dt=0.01, window=3)
    assert lead.steps() == 0
    for lag in (0.021, 0.035, 0.0, 0.012):
        lead.observe(lag)
    assert lead.steps() == 4  # 0.035 s -> 4 steps
    for lag in (0.01, 0.01, 0.01):
        lead.observe(lag)
    assert lead.steps() == 1


@pytest.mark.parametrize("planning_dt", [0.01, 0.03])
def test_the_prediction_is_the_world_under_the_plans_it_plays(planning_dt):
    sc = load_scenario("pick_place")
    world = compile_model(sc)
    planning = compile_model(sc)
    planning.opt.timestep = planning_dt  # a coarser planning model predicts at the world's
    w, p = mujoco.MjData(world), mujoco.MjData(planning)
    reset_data(sc, world, w)
    reset_data(sc, planning, p)
    rng = np.random.default_rng(0)
    plans = [
        TimedPlan(0.0, 0.02, rng.uniform(-0.5, 0.5, (4, world.nu)), 0),
        TimedPlan(0.05, 0.02, rng.uniform(-0.5, 0.5, (4, world.nu)), 1),
    ]
    predict(planning, p, plans, np.zeros(world.nu), world.opt.timestep, steps=12)
    player = PlanPlayer()
    for plan in plans:
        player.receive(plan)
    for _ in range(12):
        ctrl = player.control(w.time)[0]
        w.ctrl[:] = np.zeros(world.nu) if ctrl is None else ctrl
        mujoco.mj_step(world, w)
    assert planning.opt.timestep == planning_dt and math.isclose(p.time, w.time)
    np.testing.assert_allclose(p.qpos, w.qpos, atol=1e-12)


def test_timing_summary_counts_plans_steps_and_ages():
    steps = [
        {"kind": "step", "plan_seq": s, "age": a}
        for s, a in [(-1, 0.0), (3, 0.03), (3, 0.04), (3, 0.05), (6, 0.03), (6, 0.04), (-1, 0.0)]
    ]
    t = timing_summary(steps)
    assert t["plans"] == 2 and t["steps_per_plan"] == {"mean": 2.5, "max": 3}
    assert t["safe_steps"] == 2 and math.isclose(t["age_ms"]["max"], 50.0)
    assert timing_summary([{"kind": "step"}]) is None  # an old log


# ------------------------------------------------------------------ the world plays a plan


def _connect(port: int, scenario: str):
    ctx = zmq.Context()
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(Endpoints(port=port).control)
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.CONFLATE, 1)
    sub.connect(Endpoints(port=port).state)
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(Endpoints(port=port).command)
    sc = load_scenario(scenario)
    req.send(P.encode(P.Hello(scenario=sc.name, scenario_hash=sc.hash)))
    assert req.poll(20000), "no welcome"
    welcome = P.decode(req.recv())
    assert isinstance(welcome, P.Welcome), welcome
    return ctx, req, sub, push, welcome


def test_a_realtime_world_holds_its_start_until_the_first_command(tmp_path):
    from tests.helpers import StateWatcher

    port = free_port_block()
    server = start_server(
        "navigation", port, tmp_path / "episode.jsonl", "--mode", "realtime", "--republish", "0.05"
    )
    watcher = StateWatcher(port)
    try:
        first = watcher.latest()
        time.sleep(1.0)  # 20 steps of a 20 Hz world, were it running
        later = watcher.latest()
        assert (first.seq, first.time) == (later.seq, later.time) == (0, 0.0)
        watcher.control(port, "shutdown")
        server.wait(20)
    finally:
        watcher.close()
        stop(server)


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_the_world_plays_a_plan_between_updates_and_the_safe_control_after_it(tmp_path, mode):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    extra = (
        ["--mode", "realtime", "--realtime-factor", "2", "--command-timeout", "5"]
        if mode == "realtime"
        else ["--plan-every", "14"]
    )
    server = start_server("navigation", port, log, *extra)
    ctx, req, sub, push, welcome = _connect(port, "navigation")
    dt = welcome.dt
    knots = np.array([[0.1, 0.0], [0.2, 0.0], [0.3, -0.1], [0.0, 0.4]])
    try:
        assert sub.poll(20000)
        state = P.decode(sub.recv())
        # knots two world steps long, from a few steps after the state (time for the command to
        # arrive in real time): then the plan runs out
        lead = 4 if mode == "realtime" else 2
        t0 = state.time + lead * dt
        push.send(
            P.encode(
                P.Command(
                    session=state.session,
                    seq=state.seq,
                    ctrl=knots[0],
                    plan_ctrl=knots,
                    plan_t0=t0,
                    plan_dt=2 * dt,
                )
            )
        )
        for _ in range(200):
            assert sub.poll(20000)
            if P.decode(sub.recv()).time >= t0 + 10 * dt - 1e-9:
                break
        req.send(P.encode(P.Control(op="shutdown")))
        assert req.poll(10000)
        req.recv()
        server.wait(20)
    finally:
        for s in (req, sub, push):
            s.close(0)
        ctx.term()
        stop(server)
    records = read_log(log)
    steps = [r for r in records if r["kind"] == "step" and r["time"] > state.time + 1e-9]
    # a step record has the time after its step: the control applied at world time τ is logged
    # at τ + dt
    before = [s for s in steps if s["time"] <= t0 + 1e-9]
    played = [s for s in steps if t0 + 1e-9 < s["time"] <= t0 + 8 * dt + 1e-9]
    after = [s for s in steps if s["time"] > t0 + 8 * dt + 1e-9][:2]
    assert len(before) == lead and all(s["safe"] and s["plan_seq"] == -1 for s in before)
    assert len(played) == 8 and not any(s["safe"] for s in played)
    for i, s in enumerate(played):  # step i applies knot i // 2 (ZOH, 2 steps)
        np.testing.assert_allclose(s["ctrl"], knots[i // 2], atol=1e-12)
        assert s["plan_seq"] == state.seq and math.isclose(s["age"], (i + lead) * dt, abs_tol=1e-9)
    assert len(after) == 2 and all(s["safe"] and s["plan_seq"] == -1 for s in after)
    np.testing.assert_allclose(after[0]["ctrl"], [0.0, 0.0])  # the point robot stops
    if mode == "realtime":
        assert any(r.get("what") == "plan_ended" for r in records)


# ------------------------------------------------------------------ decoupled rates


def _navigation_with(tmp_path, timestep: float):
    from shared.config_files import shipped

    raw = yaml.safe_load((shipped("scenarios") / "navigation.yaml").read_text())
    raw["planner"]["timestep"] = timestep
    path = tmp_path / "nav.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_planning_timestep_must_be_a_whole_multiple_of_the_worlds(tmp_path):
    from shared.config import ConfigError

    with pytest.raises(
        ConfigError, match=r"planner.timestep: not a whole multiple.*0.05 × 1, 2, 3"
    ):
        load_scenario(str(_navigation_with(tmp_path, 0.07)))


def test_the_rollouts_step_at_the_planning_timestep_and_the_world_at_its_own(tmp_path):
    from planner_client.problem import build_problem

    sc = load_scenario(str(_navigation_with(tmp_path, 0.1)))
    assert sc.planner.step(sc.world) == 0.1
    assert build_problem(sc).model.opt.timestep == 0.1
    assert compile_model(sc).opt.timestep == 0.05


# ------------------------------------------------------------------ end to end


def test_a_planner_three_times_slower_than_the_world_still_navigates(tmp_path):
    """Lock-step with --plan-every 3: the world plays each plan for three steps, the planner
    shifts its warm start by three (navigation: not a chaotic episode)."""
    from m3p2i.launch import EpisodeLaunch, run_episode
    from shared.config_files import shipped

    run = run_episode(
        EpisodeLaunch(
            scenario=str(shipped("scenarios") / "navigation.yaml"),
            run_dir=tmp_path,
            plan_every=3,
            timeout=300,
        )
    )
    assert run.summary is not None and run.summary["status"] == "success", run.reason
    timing = run.summary["timing"]
    assert timing["steps_per_plan"]["max"] == 3 and timing["safe_steps"] == 0
    assert math.isclose(timing["age_ms"]["max"], 2 * 50.0)  # knots 0, 1, 2 of each plan


@pytest.mark.slow
def test_a_realtime_pick_place_succeeds_with_a_planner_under_a_third_of_the_worlds_rate(tmp_path):
    """Real time: the Panda's world steps on the wall clock while the planner is held to under a
    third of its rate, so the world plays each plan for more than 3 steps. The world runs at
    half speed (``--realtime-factor 0.5``: 50 of its 10 ms steps a wall second) and the planner
    at most 15 plans a wall second (``--max-rate``): the ratio is then the cap's, not the
    machine's, as long as the machine makes 15 plans a second (this 2-core one makes 40; a
    full-speed world against a 30/s cap, near this machine's own speed, failed on CI's machine:
    25/s succeeded 13-17 of 20 here). Success is a rate: 18 of 20 seeds succeeded so
    (``pick_place_rt_half`` in docs/bench/realtime), so one of two must (both failing: well under
    1 %; seed 2 runs only when seed 1 fails); the world must really have played each plan for
    more than 3 steps on average. A
    success chains the template's actions and stacks within Eq. 26's 1 cm and φ 0.01 (the suite's
    one end-to-end run of the plain pick_place.yaml)."""
    from m3p2i.launch import EpisodeLaunch, run_episode
    from shared.config_files import shipped

    outcomes = []
    for seed in (1, 2):
        run = run_episode(
            EpisodeLaunch(
                scenario=str(shipped("scenarios") / "pick_place.yaml"),
                run_dir=tmp_path / str(seed),
                seed=seed,
                mode="realtime",
                max_rate=15.0,
                realtime_factor=0.5,
                timeout=300,
            )
        )
        assert run.summary is not None, run.reason
        assert run.summary["timing"]["steps_per_plan"]["mean"] > 3.0
        outcomes.append(run.summary["status"])
        if run.summary["status"] == "success":
            actions = [a for _, a in run.summary["actions"]]
            assert list(dict.fromkeys(actions))[:4] == ["reach", "pick", "move2place", "place"]
            measures = run.summary["measures"]
            assert measures["position error cube_a-cube_b"] < 0.01
            assert measures["orientation error cube_a-cube_b"] < 0.01
            break
    assert "success" in outcomes, outcomes


def test_a_command_answering_a_state_older_than_the_timeout_is_dropped(tmp_path):
    """A command held up by the link (sent before a cut, delivered after it) answers a state
    long gone: played, its lag (published as ``state.lag``) would make the planner date every
    later plan that far ahead. The world drops it and logs why."""
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log, "--mode", "realtime", "--command-timeout", "0.3")
    ctx, req, sub, push, _ = _connect(port, "navigation")

    def command(state: P.State, seq: int) -> bytes:
        knots = np.zeros((40, 2))
        return P.encode(
            P.Command(
                session=state.session,
                seq=seq,
                ctrl=knots[0],
                plan_ctrl=knots,
                plan_t0=state.time,
                plan_dt=0.05,
            )
        )

    try:
        assert sub.poll(20000)
        first = P.decode(sub.recv())
        push.send(command(first, first.seq))  # starts the world's clock
        lags = []
        while True:
            assert sub.poll(20000)
            state = P.decode(sub.recv())
            if state.time >= 0.6:
                break
        push.send(command(state, 1))  # answers state 1 (t = 0.05 s), 0.55 s ago
        for _ in range(6):
            assert sub.poll(20000)
            lags.append(P.decode(sub.recv()).lag)
        req.send(P.encode(P.Control(op="shutdown")))
        assert req.poll(10000)
        req.recv()
        server.wait(20)
    finally:
        for s in (req, sub, push):
            s.close(0)
        ctx.term()
        stop(server)
    records = read_log(log)
    dropped = [r for r in records if r.get("what") == "stale_command"]
    assert [r["seq"] for r in dropped] == [1] and dropped[0]["age"] > 0.3
    assert not any(r["kind"] == "step" and r["plan_seq"] == 1 for r in records)
    assert max(lags) < 0.3, lags
