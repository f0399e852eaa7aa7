"""Control ops and an episode's record of them: a plain ``reset`` mid-episode is followed by a
whole episode, a lock-step world plays a plan dated ahead of it from its date on (the previous
plan until then), a kept world never overwrites a log, and the summary's ``steps`` counts world
steps."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from planner_client.build import build_controller
from planner_client.cli import with_delays
from server.app import ServerOptions, WorldServer
from server.evaluation.log_reader import read_log
from server.inprocess import build_episode, run_episode
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from tests.cli.test_view_control import _ask
from tests.helpers import (
    StateWatcher,
    free_port_block,
    start_planner,
    start_server,
    stop,
    wait_episode,
    wait_until,
)


def _steps(records: list[dict]) -> list[dict]:
    return [r for r in records if r.get("kind") == "step"]


def _carrying(path) -> bool:
    """Whether the log has a step of the action ``move2place`` (the robot carries the cube)."""
    try:
        with path.open() as f:
            return any('"move2place"' in line and '"kind": "step"' in line for line in f)
    except FileNotFoundError:
        return False


@pytest.mark.slow
def test_a_reset_while_carrying_is_followed_by_a_whole_successful_episode(tmp_path):
    """The view's Reset button mid-episode: the world restarts, and the planner must start over
    with it (task layer, beliefs, welds of held objects), not carry on with the cube it held.
    Robust: pick_place succeeds from its start for this seed (and others) in ~3.3 s; the reset
    planner is a fresh one, so the restarted part is the same episode as a fresh run's."""
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("pick_place", port, log, "--seed", "0")
    planner = start_planner("pick_place", port, "--seed", "0")
    watcher = StateWatcher(port)
    try:
        assert wait_until(lambda: _carrying(log), timeout=300, period=0.2), (
            "the robot never carried the cube"
        )
        watcher.control(port, "reset")
        out = wait_episode(server, planner, timeout=600)
        planner.communicate(timeout=60)
    finally:
        watcher.close()
        stop(server, planner)
    records = read_log(log)
    summary = records[-1]
    assert summary["kind"] == "summary" and summary["status"] == "success", out
    (reset,) = [r for r in records if r.get("what") == "reset"]
    steps = _steps(records)
    before = [s for s in steps if s["wall"] < reset["wall"]]
    after = [s for s in steps if s["wall"] > reset["wall"]]
    assert before[-1]["time"] >= 2.0 and after[0]["time"] < 0.05  # the world restarted
    assert reset["time"] == pytest.approx(before[-1]["time"])
    assert summary["resets"] == 1
    assert after[-1]["time"] < 10.0  # the restarted part, not a time-out


def _command(episode, ctrl, t0: float | None = None, knots: int = 20) -> P.Command:
    """The command answering ``episode``'s newest state: ``ctrl`` held over ``knots`` knots of
    a plan dated ``t0`` (None: the state's time, what a lock-step planner sends)."""
    ctrl = np.asarray(ctrl, float)
    t0 = episode.world.time if t0 is None else t0
    return P.Command(
        session=episode.session,
        seq=episode.seq,
        ctrl=ctrl,
        plan_ctrl=np.tile(ctrl, (knots, 1)),
        plan_t0=t0,
        plan_dt=episode.dt,
    )


def test_the_summarys_steps_count_world_steps_not_control_ops(tmp_path):
    """``move`` and ``reset`` publish new states (the state number goes on) but step nothing."""
    episode = build_episode("pick_place", seed=0, log_path=tmp_path / "e.jsonl")
    try:
        for _ in range(3):
            episode.apply(None)
        episode.move("cube_a", np.array([0.5, 0.0, 0.45]))
        episode.apply(None)
        episode.reset()
        for _ in range(2):
            episode.apply(None)
        episode.finish()
    finally:
        episode.close()
    records = read_log(tmp_path / "e.jsonl")
    assert len(_steps(records)) == 6
    assert records[-1]["steps"] == 6 and records[-1]["metrics"]["steps"] == 6


def test_lockstep_plays_the_previous_plan_until_a_plan_dated_ahead_starts(tmp_path):
    """A planner that dates its plan ahead of the state (a declared state delay) against a
    lock-step world that publishes at once: the plan playing goes on until the new one's
    ``plan_t0`` (docs/protocol.md, "From plan_t0 on"), as in real time; not the safe control."""
    episode = build_episode("navigation", seed=0, log_path=tmp_path / "e.jsonl")
    dt = episode.dt
    a, b = np.array([0.1, -0.1]), np.array([-0.1, 0.1])
    try:
        episode.publish()
        episode.play(_command(episode, a))  # state 0: a, from now on
        first = episode.seq - 1
        episode.publish()
        ahead = _command(episode, b, t0=episode.world.time + 2 * dt)  # state 1: b, 2 steps on
        episode.play(ahead, steps=4)
        episode.finish()
    finally:
        episode.close()
    steps = _steps(read_log(tmp_path / "e.jsonl"))
    assert [s["safe"] for s in steps] == [False] * 5
    assert [s["plan_seq"] for s in steps] == [first, first, first, ahead.seq, ahead.seq]
    np.testing.assert_allclose([s["ctrl"] for s in steps], [a, a, a, b, b])


def test_lockstep_with_a_planner_declaring_a_state_delay_moves_the_robot(tmp_path):
    """The whole loop: a planner declaring a state delay of 3 world steps dates each plan 3
    steps ahead; a world without that delay plays each from then on. Before the fix every step
    was the safe control and the robot never moved. Robust: a property of every step after the
    first plan's date, whatever the seed."""
    nav = load_scenario("navigation")
    ahead = 3
    sc = with_delays(nav, None, ahead * nav.world.timestep * 1000)
    one_thread = partial(build_controller, threads=2)
    result = run_episode(sc, one_thread, seed=0, log_path=tmp_path / "e.jsonl", max_steps=30)
    steps = _steps(read_log(result.log_path))
    assert len(steps) == 30
    assert all(s["safe"] for s in steps[:ahead])  # before the first plan's date
    assert not any(s["safe"] for s in steps[ahead:])  # then always a plan, 3 states old
    assert all(s["plan_seq"] == s["seq"] - 1 - ahead for s in steps[ahead:])
    start, end = np.array(steps[0]["qpos"][:2]), np.array(steps[-1]["qpos"][:2])
    assert np.linalg.norm(end - start) > 0.1


def test_a_kept_world_never_overwrites_the_log_of_a_seed_it_served(tmp_path):
    """``--keep-serving``: a reset to a seed already served begins an episode whose log has a
    path of its own; the finished episode's log keeps its steps and summary."""
    server = WorldServer(
        load_scenario("navigation"),
        Endpoints(port=free_port_block()),
        tmp_path / "seed-{seed}.jsonl",
        ServerOptions(keep_serving=True),
        seed=3,
    )
    try:
        server.episode.apply(None)
        first = server.log.path
        paths = [first]
        for _ in range(2):
            assert isinstance(_ask(server, P.Control(op="reset", seed=3)), P.Control)
            server.serve_episode()  # as run() does: this episode ends ...
            server.next_episode()  # ... and the seed's next begins
            paths.append(server.log.path)
    finally:
        server.log.close()
        server.close()
    assert paths == [first, tmp_path / "seed-3-2.jsonl", tmp_path / "seed-3-3.jsonl"]
    records = read_log(first)
    assert len(_steps(records)) == 1 and records[-1]["kind"] == "summary"
    assert read_log(paths[1])[-1]["kind"] == "summary"
    assert [read_log(p)[0]["seed"] for p in paths] == [3, 3, 3]
