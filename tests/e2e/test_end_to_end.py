"""Both processes over loopback: navigation reaches its goal, mismatches are refused, a dead
planner leaves the robot held still, and bad messages do not crash the world."""

from __future__ import annotations

import time

import numpy as np
import pytest
import yaml
import zmq

from server.episode_log import read_log
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import SCENARIO_DIR
from tests.helpers import (
    StateWatcher,
    free_port_block,
    start_planner,
    start_server,
    stop,
    wait_until,
)

pytestmark = pytest.mark.slow


def test_lockstep_navigation_reaches_the_goal(tmp_path):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log)
    planner = start_planner("navigation", port)
    try:
        out, _ = server.communicate(timeout=240)
        planner_out, _ = planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode == 0, out
    assert "success" in out and "final distance robot-goal" in out
    assert planner.returncode == 0, planner_out
    records = read_log(log)
    summary = records[-1]
    assert summary["kind"] == "summary" and summary["status"] == "success"
    assert summary["measures"]["distance robot-goal"] <= 0.1
    steps = [r for r in records if r["kind"] == "step"]
    assert len(steps) == summary["steps"] and all(not s["safe"] for s in steps)


def test_a_rate_cap_in_lock_step_is_named_for_what_it_does(tmp_path):
    """--max-rate rehearses a slow planner against a real-time world; a lock-step world waits
    for every plan, so there it only slows the run: the planner says so once."""
    port = free_port_block()
    server = start_server("navigation", port, tmp_path / "episode.jsonl")
    planner = start_planner("navigation", port, "--max-rate", "1000")
    try:
        out, _ = server.communicate(timeout=240)
        planner_out, _ = planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode == 0 and "success" in out, out
    assert planner_out.count("--max-rate 1000: a lock-step world waits for every plan") == 1


def _navigation_steps(tmp_path, *server_args: str) -> list[list[float]]:
    port = free_port_block()
    log = tmp_path / f"episode-{port}.jsonl"
    server = start_server("navigation", port, log, *server_args)
    planner = start_planner("navigation", port)
    try:
        out, _ = server.communicate(timeout=240)
        planner.communicate(timeout=30)
    finally:
        stop(server, planner)
    assert server.returncode == 0, out
    return [r["qpos"] for r in read_log(log) if r["kind"] == "step"]


def test_lockstep_episode_does_not_depend_on_re_published_states(tmp_path):
    """The world re-sends a waiting state (--republish); a busy planner gets it again while
    still planning. Answering it without planning again keeps the episode the same."""
    quiet = _navigation_steps(tmp_path)
    flooded = _navigation_steps(tmp_path, "--republish", "0.001")
    assert len(flooded) == len(quiet)
    np.testing.assert_array_equal(np.array(flooded), np.array(quiet))


def test_scenario_mismatch_is_refused_with_a_clear_message(tmp_path):
    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["world"]["objects"][0]["pos"][0] += 0.5
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(raw))
    port = free_port_block()
    server = start_server("navigation", port, tmp_path / "log.jsonl")
    planner = start_planner(str(other), port)
    try:
        out, _ = planner.communicate(timeout=60)
    finally:
        stop(server, planner)
    assert planner.returncode == 3
    assert "scenario mismatch" in out and "same scenario file" in out


def test_killed_planner_leaves_the_robot_held_still(tmp_path):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log, "--mode", "realtime", "--command-timeout", "0.3")
    planner = start_planner("navigation", port)
    watcher = StateWatcher(port)
    try:
        assert wait_until(lambda: np.abs(watcher.latest().qvel).max() > 0.3, timeout=60), (
            "the robot never started moving"
        )
        planner.kill()
        planner.wait()
        time.sleep(0.8)  # > command timeout + velocity servo settling
        a = watcher.latest()
        time.sleep(0.5)
        b = watcher.latest()
        assert a.status == "running" and b.time > a.time
        assert np.abs(b.qvel).max() < 1e-3
        np.testing.assert_allclose(a.qpos, b.qpos, atol=1e-3)
        watcher.control(port, "shutdown")
        server.wait(10)
    finally:
        watcher.close()
        stop(server, planner)
    events = [r.get("what") for r in read_log(log) if r["kind"] == "event"]
    assert "commands_stale" in events
    assert read_log(log)[-1]["kind"] == "summary"


def test_world_survives_garbage_and_logs_the_rejections(tmp_path):
    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log)
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(Endpoints(port=port).command)
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(Endpoints(port=port).control)
    try:
        for frame in (b"\x00garbage", b"\x93\x01\x02\x03", b"A" * 100_000):
            push.send(frame)
        req.send(b"not msgpack at all")
        assert req.poll(30000), "the world did not answer the bad request"
        reply = P.decode(req.recv())
        assert isinstance(reply, P.Error) and "refused" in reply.reason
        req.send(P.encode(P.Hello(scenario="navigation", scenario_hash="0" * 16)))
        assert req.poll(5000)
        reply = P.decode(req.recv())
        assert isinstance(reply, P.Error) and "scenario mismatch" in reply.reason
        assert server.poll() is None, "the world crashed"
        assert wait_until(
            lambda: sum(r.get("what") == "rejected" for r in read_log(log)) >= 4, timeout=10
        ), "bad commands were not all logged as rejected"
        assert server.poll() is None, "the world crashed"
        req.send(P.encode(P.Control(op="shutdown")))
        assert req.poll(5000)
        req.recv()
        server.wait(10)
    finally:
        push.close()
        req.close()
        ctx.term()
        stop(server)
    rejected = [r for r in read_log(log) if r.get("what") == "rejected"]
    assert len(rejected) >= 4
    assert read_log(log)[-1]["kind"] == "summary"


def test_planner_outlives_a_server_restart(tmp_path):
    port = free_port_block()
    # the first world runs in real time so that it is still mid-episode when it is killed
    first = start_server("navigation", port, tmp_path / "first.jsonl", "--mode", "realtime")
    planner = start_planner("navigation", port)
    watcher = StateWatcher(port)
    try:
        assert wait_until(lambda: watcher.latest().seq > 10, timeout=60), "no progress"
        first.kill()  # the world dies mid-episode
        first.wait()
        time.sleep(1.0)
        assert planner.poll() is None, "the planner died with the server"
        second = start_server("navigation", port, tmp_path / "second.jsonl")
        out, _ = second.communicate(timeout=240)
        planner_out, _ = planner.communicate(timeout=30)
    finally:
        watcher.close()
        stop(first, planner)
    assert second.returncode == 0 and "success" in out, out
    assert planner.returncode == 0, planner_out
    first_log = read_log(tmp_path / "first.jsonl")
    assert not any(r["kind"] == "summary" for r in first_log), "the first world was not killed"
    assert any(r.get("what") == "handshake" for r in read_log(tmp_path / "second.jsonl"))


def test_ctrl_c_keeps_the_episode_log(tmp_path):
    import signal

    port = free_port_block()
    log = tmp_path / "episode.jsonl"
    server = start_server("navigation", port, log, "--mode", "realtime")
    planner = start_planner("navigation", port)
    watcher = StateWatcher(port)
    try:
        assert wait_until(lambda: watcher.latest().seq > 10, timeout=60), "no progress"
        server.send_signal(signal.SIGINT)
        server.wait(15)
    finally:
        watcher.close()
        stop(server, planner)
    records = read_log(log)
    steps = [r for r in records if r["kind"] == "step"]
    assert records[0]["kind"] == "header" and len(steps) > 10
    assert records[-1]["kind"] == "summary" and records[-1]["status"] == "stopped"
    assert records[-1]["steps"] == steps[-1]["seq"]


def test_protocol_version_mismatch_is_refused(tmp_path):
    import msgpack

    port = free_port_block()
    server = start_server("navigation", port, tmp_path / "log.jsonl")
    ctx = zmq.Context()
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(Endpoints(port=port).control)
    try:
        req.send(
            msgpack.packb(
                {"type": "hello", "v": 99, "scenario": "navigation", "scenario_hash": "x"}
            )
        )
        assert req.poll(30000)
        reply = P.decode(req.recv())
        assert isinstance(reply, P.Error) and "protocol version 99 not supported" in reply.reason
    finally:
        req.close()
        ctx.term()
        stop(server)
