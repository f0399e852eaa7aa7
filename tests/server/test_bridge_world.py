"""Hardware bridges: a world written against docs/protocol.md alone, and a user's World class
served by ``m3p2i-server --world`` (docs/bridge.md), each driving the real planner process to
the navigation goal in lock-step.

The two episodes share one planner process (``--keep-running``: it handshakes again with each
new world on its port), as a planner outlives a bridge restart; its start-up is most of the
time an episode takes here."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq
from typer.testing import CliRunner

from m3p2i.launch import free_port_block
from server.cli import app as server_app
from server.evaluation.log_reader import read_log, steps
from server.interface import WorldLoadError, load_world_class
from shared.scenario import load_scenario
from shared.scene import compile_model, initial_data
from tests.bridge_worlds import KinematicBase
from tests.helpers import ENV, start_planner, stop

ROOT = Path(__file__).resolve().parents[2]
GOAL = np.array([-3.0, 3.0])  # configs/scenarios/navigation.yaml: episode.success
WITHIN = 0.1


# ------------------------------------------------------------------ a bridge from the spec only


def _array(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"nd": True, "dtype": "<f8", "shape": list(a.shape), "data": a.tobytes()}


def _read_array(m: dict) -> np.ndarray:
    return np.frombuffer(m["data"], dtype=m["dtype"]).reshape(m["shape"])


def raw_bridge(
    port: int,
    scenario_hash: str,
    dt: float,
    mocap_pos: list,
    mocap_quat: list,
    result: dict,
    deadline_s: float = 60.0,
) -> None:
    """A lock-step world for the navigation scenario written with zmq and msgpack only, from
    docs/protocol.md: a kinematic point robot (qpos = x, y; ctrl = world velocity, m/s,
    clipped to +-1.5) and the scenario's fixed obstacles as perception would report them."""
    ctx = zmq.Context()
    rep, pub, pull = ctx.socket(zmq.REP), ctx.socket(zmq.PUB), ctx.socket(zmq.PULL)
    for s, offset in ((rep, 0), (pub, 1), (pull, 2)):
        s.setsockopt(zmq.LINGER, 0)
        s.bind(f"tcp://127.0.0.1:{port + offset}")
    poller = zmq.Poller()
    poller.register(rep, zmq.POLLIN)
    poller.register(pull, zmq.POLLIN)
    session, seq, t, status = "bridge01", 0, 0.0, "running"
    qpos, qvel = np.zeros(2), np.zeros(2)
    mpos, mquat = np.array(mocap_pos, float), np.array(mocap_quat, float)

    def publish() -> None:
        pub.send(
            msgpack.packb(
                {
                    "type": "state",
                    "v": 2,
                    "session": session,
                    "seq": seq,
                    "time": t,
                    "qpos": _array(qpos),
                    "qvel": _array(qvel),
                    "act": _array(np.zeros(0)),
                    "mocap_pos": _array(mpos),
                    "mocap_quat": _array(mquat),
                    "status": status,
                }
            )
        )

    end = time.monotonic() + deadline_s
    ended_at = None
    last_pub = 0.0
    try:
        while time.monotonic() < end:
            if ended_at is not None and time.monotonic() - ended_at > 0.5:
                break  # the final state was published long enough
            events = dict(poller.poll(50))
            if rep in events:
                msg = msgpack.unpackb(rep.recv())
                if (
                    msg.get("type") == "hello"
                    and msg.get("v") == 2
                    and msg.get("scenario_hash") == scenario_hash
                ):
                    rep.send(
                        msgpack.packb(
                            {
                                "type": "welcome",
                                "v": 2,
                                "scenario": msg["scenario"],
                                "scenario_hash": scenario_hash,
                                "mode": "lockstep",
                                "dt": dt,
                                "nu": 2,
                                "session": session,
                            }
                        )
                    )
                    result["handshakes"] = result.get("handshakes", 0) + 1
                else:
                    rep.send(msgpack.packb({"type": "error", "v": 2, "reason": "wrong hello"}))
                publish()
            if pull in events:
                while True:
                    try:
                        cmd = msgpack.unpackb(pull.recv(zmq.NOBLOCK))
                    except zmq.Again:
                        break
                    if (
                        cmd.get("type") != "command"
                        or cmd.get("session") != session
                        or cmd.get("seq") != seq
                        or status != "running"
                    ):
                        continue  # outdated, or a repeat of an answered state
                    ctrl = np.clip(_read_array(cmd["ctrl"]), -1.5, 1.5)
                    qvel = ctrl.copy()
                    qpos = qpos + ctrl * dt
                    t, seq = t + dt, seq + 1
                    if np.linalg.norm(qpos - GOAL) <= WITHIN:
                        status = "success"
                    elif t >= 30.0 - 1e-9:
                        status = "timeout"
                    if status != "running":
                        ended_at = time.monotonic()
                    publish()
                    last_pub = time.monotonic()
            if time.monotonic() - last_pub >= 0.2:  # the pending state, for late subscribers
                publish()
                last_pub = time.monotonic()
    finally:
        result.update(status=status, qpos=qpos, time=t, steps=seq)
        for s in (rep, pub, pull):
            s.close(0)
        ctx.term()


@pytest.fixture(scope="module")
def planner():
    """A navigation planner on a free port block, planning for whichever world is there."""
    port = free_port_block()
    proc = start_planner("navigation", port, "--keep-running")
    try:
        yield port, proc
    finally:
        stop(proc)


def _alive(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        raise AssertionError(
            f"the planner exited (code {proc.returncode}):\n{proc.communicate()[0]}"
        )


def test_a_bridge_written_from_the_protocol_spec_drives_the_planner_to_the_goal(planner):
    port, proc = planner
    sc = load_scenario("navigation")
    model = compile_model(sc)
    start = initial_data(sc, model)
    assert model.nq == 2 and model.nu == 2  # the bridge's kinematic robot is this model's
    result: dict = {}
    bridge = threading.Thread(
        target=raw_bridge,
        daemon=True,
        args=(
            port,
            sc.hash,
            float(model.opt.timestep),
            start.mocap_pos.tolist(),
            start.mocap_quat.tolist(),
            result,
        ),
    )
    bridge.start()
    bridge.join(90)
    _alive(proc)
    assert not bridge.is_alive(), "the bridge's episode did not end"
    assert result["status"] == "success", result
    assert np.linalg.norm(result["qpos"] - GOAL) <= WITHIN
    assert result["handshakes"] == 1


# ------------------------------------------------------------------ --world: a user's class


def test_a_user_world_class_is_served_with_world(planner, tmp_path):
    port, proc = planner
    log = tmp_path / "episode.jsonl"
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "server",
            "--scenario",
            "navigation",
            "--port",
            str(port),
            "--log",
            str(log),
            "--world",
            "tests.bridge_worlds:KinematicBase",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )
    try:
        out = server.communicate(timeout=90)[0]
        _alive(proc)
        assert server.returncode == 0, out
        assert out.startswith("success") or "\nsuccess" in out, out
    finally:
        stop(server)
    records = read_log(log)
    assert records[0]["world"] == "tests.bridge_worlds:KinematicBase"
    summary = records[-1]
    assert summary["kind"] == "summary" and summary["status"] == "success"
    assert summary["measures"]["distance robot-goal"] <= WITHIN
    # the user's class moved the robot: kinematically, each step exactly its clipped control
    qpos = np.array([s["qpos"] for s in steps(records)])
    ctrl = np.array([s["ctrl"] for s in steps(records)])
    dt = records[0]["dt"]
    np.testing.assert_allclose(np.diff(qpos, axis=0), ctrl[1:] * dt, atol=1e-12)
    np.testing.assert_allclose(qpos[0], ctrl[0] * dt, atol=1e-12)  # from the origin
    assert np.abs(ctrl).max() <= 1.5


# ------------------------------------------------------------------ real time: the safe stops


def test_a_realtime_bridge_is_stopped_on_stale_commands_on_pause_and_at_the_end(tmp_path):
    from server.app import ServerOptions, WorldServer
    from shared import protocol as P
    from shared.endpoints import Endpoints
    from tests.bridge_worlds import RecordingBase

    port = free_port_block()
    server = WorldServer(
        load_scenario("navigation"),
        Endpoints(port=port),
        tmp_path / "e.jsonl",
        ServerOptions(mode="realtime", command_timeout=0.2, republish=0.05),
        world=RecordingBase,
    )
    world = server.world
    runner = threading.Thread(target=server.run, daemon=True)
    runner.start()
    ctx = zmq.Context()
    req, push = ctx.socket(zmq.REQ), ctx.socket(zmq.PUSH)
    for s, addr in ((req, Endpoints(port=port).control), (push, Endpoints(port=port).command)):
        s.setsockopt(zmq.LINGER, 0)
        s.connect(addr)

    def ask(msg):
        req.send(P.encode(msg))
        assert req.poll(10000), "the world did not answer"
        return P.decode(req.recv())

    go = np.array([1.0, 0.0])
    try:
        sc = load_scenario("navigation")
        session = ask(P.Hello(scenario=sc.name, scenario_hash=sc.hash)).session

        def drive(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                push.send(P.encode(P.Command(session=session, seq=0, ctrl=go)))
                time.sleep(0.02)

        drive(0.3)
        assert any(np.array_equal(c, go) for c in world.sent)
        assert isinstance(ask(P.Control(op="pause")), P.Control)
        np.testing.assert_array_equal(world.sent[-1], [0.0, 0.0])  # stopped before the echo
        assert isinstance(ask(P.Control(op="resume")), P.Control)
        drive(0.3)
        time.sleep(0.6)  # commands stale after 0.2 s: the watchdog's safe control
        stale_x = world.data.qpos[0]
        np.testing.assert_array_equal(world.sent[-1], [0.0, 0.0])
        time.sleep(0.2)
        assert world.data.qpos[0] == stale_x > 0.0  # it moved, then held still
        ask(P.Control(op="shutdown"))
        runner.join(10)
        assert not runner.is_alive()
    finally:
        req.close(0)
        push.close(0)
        ctx.term()
        if runner.is_alive():
            server.stop()
            runner.join(10)
    np.testing.assert_array_equal(world.sent[-1], [0.0, 0.0])  # the episode's end
    records = read_log(tmp_path / "e.jsonl")
    assert [r["what"] for r in records if r.get("what", "").startswith("commands_")] == [
        "commands_fresh",
        "commands_stale",
    ]
    stale_at = next(i for i, r in enumerate(records) if r.get("what") == "commands_stale")
    after = [r for r in records[stale_at:] if r["kind"] == "step"]
    assert after and all(r["safe"] and r["ctrl"] == [0.0, 0.0] for r in after)
    assert records[-1]["status"] == "stopped"


def test_a_bridge_that_fails_mid_episode_is_stopped_and_its_log_summarised(tmp_path):
    from server.app import ServerOptions, WorldServer
    from server.interface import WorldError
    from shared import protocol as P
    from shared.endpoints import Endpoints
    from tests.bridge_worlds import LosingTrack

    port = free_port_block()
    server = WorldServer(
        load_scenario("navigation"),
        Endpoints(port=port),
        tmp_path / "e.jsonl",
        ServerOptions(mode="realtime"),
        world=LosingTrack,
    )
    world, failure = server.world, []

    def run() -> None:
        try:
            server.run()
        except WorldError as exc:
            failure.append(exc)

    runner = threading.Thread(target=run, daemon=True)
    runner.start()
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(Endpoints(port=port).command)
    try:
        end = time.monotonic() + 5
        while runner.is_alive() and time.monotonic() < end:
            push.send(
                P.encode(
                    P.Command(session=server.episode.session, seq=0, ctrl=np.array([1.0, 0.0]))
                )
            )
            time.sleep(0.02)
        runner.join(5)
        assert not runner.is_alive()
    finally:
        push.close(0)
        ctx.term()
        if runner.is_alive():
            server.stop()
    assert [str(e) for e in failure] == ["motion capture lost the base"]
    np.testing.assert_array_equal(world.sent[-1], [0.0, 0.0])  # the safe stop
    summary = read_log(tmp_path / "e.jsonl")[-1]
    assert summary["kind"] == "summary" and summary["status"] == "stopped"


# ------------------------------------------------------------------ --world: bad values


@pytest.mark.parametrize(
    "value, expected",
    [
        ("tests.bridge_worlds", "expected package.module:Class"),
        ("tests.no_such_module:X", "no module named 'tests.no_such_module'"),
        ("tests.bridge_worlds:Missing", "has no 'Missing'"),
        ("tests.bridge_worlds:NotAWorld", "is not a subclass of server.interface.World"),
        ("tests.bridge_worlds:Unfinished", "leaves abstract: sense"),
    ],
)
def test_a_bad_world_value_is_named_with_what_was_expected(value, expected):
    with pytest.raises(WorldLoadError) as err:
        load_world_class(value)
    assert value in str(err.value) and expected in str(err.value)


def test_world_loads_the_class_it_names():
    assert load_world_class("tests.bridge_worlds:KinematicBase") is KinematicBase


def test_the_server_refuses_a_bad_world_before_it_starts(tmp_path):
    result = CliRunner().invoke(
        server_app,
        [
            "--scenario",
            "navigation",
            "--log",
            str(tmp_path / "e.jsonl"),
            "--world",
            "tests.bridge_worlds:NotAWorld",
        ],
    )
    assert result.exit_code == 2
    assert "tests.bridge_worlds:NotAWorld" in result.output and "not a subclass" in result.output
    assert not (tmp_path / "e.jsonl").exists()
    checked = CliRunner().invoke(
        server_app,
        ["--scenario", "navigation", "--check", "--world", "tests.bridge_worlds:Missing"],
    )
    assert checked.exit_code == 2 and "has no 'Missing'" in checked.output
    assert (
        CliRunner()
        .invoke(
            server_app,
            ["--scenario", "navigation", "--check", "--world", "tests.bridge_worlds:KinematicBase"],
        )
        .exit_code
        == 0
    )


def test_the_kinematic_base_follows_the_bridge_contract():
    world = KinematicBase(load_scenario("navigation"))
    world.reset()
    assert world.time == 0.0 and world.status == "running"
    world.step(np.array([3.0, -1.0]))  # clipped to the actuators' +-1.5
    s = world.state()
    np.testing.assert_allclose(s.qpos, [1.5 * world.dt, -world.dt])
    assert s.time == pytest.approx(world.dt)
    np.testing.assert_allclose(world.ctrl, [1.5, -1.0])
    world.stop()
    np.testing.assert_array_equal(world.ctrl, [0.0, 0.0])
    with pytest.raises(ValueError, match="cannot move objects"):
        world.move_object("pillar", [0.0, 0.0, 0.2])


# ------------------------------------------------------------------ docs/bridge.md


def test_the_bridge_guide_code_is_python():
    text = (ROOT / "docs" / "bridge.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "docs/bridge.md has no python example"
    for block in blocks:
        ast.parse(block)
