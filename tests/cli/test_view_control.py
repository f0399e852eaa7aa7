"""The control ops a browser view sends: ``move`` an object (accepted and logged as a
disturbance, refused with a reason for a robot body or an unknown name), ``pause``/``resume``;
and their encoding on the wire. The world is served in this thread: a REQ is sent, the server
polls once, the reply is read."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import zmq

from m3p2i.launch import free_port_block
from server.app import WorldServer
from server.evaluation.log_reader import read_log
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario


@pytest.fixture
def world(tmp_path):
    servers = []

    def make(name: str) -> WorldServer:
        server = WorldServer(
            load_scenario(name), Endpoints(port=free_port_block()), tmp_path / f"{name}.jsonl"
        )
        servers.append(server)
        return server

    yield make
    for server in servers:  # a server left open blocks its ZeroMQ context: the next test hangs
        server.log.close()
        server.close()


def _ask(server: WorldServer, msg: P.Control):
    """Send ``msg`` to the server's control socket, let it serve, return the decoded reply."""
    ctx = zmq.Context.instance()
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(
        Endpoints(
            port=int(server.rep.getsockopt_string(zmq.LAST_ENDPOINT).rsplit(":", 1)[1])
        ).control
    )
    try:
        req.send(P.encode(msg))
        for _ in range(50):
            server.serve(0.05)
            if req.poll(0):
                return P.decode(req.recv(), expect=("control", "error"))
        raise AssertionError("the world did not answer")
    finally:
        req.close(0)


def _events(server: WorldServer, what: str) -> list[dict]:
    return [r for r in read_log(server.log.path) if r.get("what") == what]


def test_a_moved_cube_is_published_and_logged_as_a_disturbance(world):
    server = world("pick_place")
    half = np.sqrt(0.5)
    seq = server.episode.seq
    reply = _ask(
        server,
        P.Control(
            op="move",
            object="cube_a",
            pos=np.array([0.5, 0.1, 1.1]),
            quat=np.array([half, 0.0, 0.0, half]),
        ),
    )
    assert isinstance(reply, P.Control) and reply.op == "move"
    cube = server.world.model.body("cube_a")
    np.testing.assert_allclose(server.world.data.xpos[cube.id], [0.5, 0.1, 1.1])
    np.testing.assert_allclose(server.world.data.xquat[cube.id], [half, 0, 0, half], atol=1e-12)
    # a new state: a lock-step world now waits for the command answering the moved world
    assert server.episode.seq == seq + 1
    state = server.world.state()
    adr = server.world.model.jnt_qposadr[cube.jntadr[0]]
    np.testing.assert_allclose(state.qpos[adr : adr + 3], [0.5, 0.1, 1.1])
    (event,) = _events(server, "disturbance")
    assert event["object"] == "cube_a" and event["source"] == "control"
    np.testing.assert_allclose(event["pos"], [0.5, 0.1, 1.1])
    np.testing.assert_allclose(event["quat"], [half, 0, 0, half])


def test_a_fixed_obstacle_moves_through_its_mocap_body(world):
    server = world("push_dynamic_obstacle")
    name = next(o.name for o in server.scenario.world.objects if o.fixed)
    reply = _ask(server, P.Control(op="move", object=name, pos=np.array([1.0, -2.0, 0.2])))
    assert isinstance(reply, P.Control)
    mocap = server.world.model.body_mocapid[server.world.model.body(name).id]
    np.testing.assert_allclose(server.world.data.mocap_pos[mocap], [1.0, -2.0, 0.2])


@pytest.mark.parametrize(
    "name, reason",
    [
        ("panda_link3", "'panda_link3' is part of the robot or the arena, not a scenario object"),
        ("finger_left", "'finger_left' is part of the robot or the arena"),  # a geom's name
        ("floor", "'floor' is part of the robot or the arena"),
        ("no_such_cube", "unknown object 'no_such_cube'"),
    ],
)
def test_moving_a_robot_body_or_an_unknown_name_is_refused_with_the_reason(world, name, reason):
    server = world("pick_place")
    qpos = server.world.data.qpos.copy()
    seq = server.episode.seq
    reply = _ask(server, P.Control(op="move", object=name, pos=np.array([0.5, 0.0, 1.2])))
    assert isinstance(reply, P.Error)
    assert reason in reply.reason and "cube_a" in reply.reason  # names what can be moved
    np.testing.assert_array_equal(server.world.data.qpos, qpos)  # nothing moved
    assert server.episode.seq == seq
    assert not _events(server, "disturbance")
    (refused,) = _events(server, "control_refused")
    assert refused["object"] == name and reason in refused["reason"]


def test_a_paused_lockstep_world_takes_no_command_until_resumed(world):
    server = world("navigation")
    assert isinstance(_ask(server, P.Control(op="pause")), P.Control)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.connect(server.pull.getsockopt_string(zmq.LAST_ENDPOINT))
    resume = zmq.Context.instance().socket(zmq.REQ)
    resume.setsockopt(zmq.LINGER, 0)
    resume.connect(server.rep.getsockopt_string(zmq.LAST_ENDPOINT))
    cmd = P.encode(
        P.Command(
            session=server.episode.session,
            seq=server.episode.seq,
            ctrl=np.zeros(server.world.model.nu),
        )
    )
    try:
        server.opt.republish = 0.05
        wanted = [lambda c: c.seq == server.episode.seq]

        def send_then_wait():
            push.send(cmd)
            return server.await_command(wanted[0])

        # paused: the command is dropped; await_command would wait for ever, so resume from a
        # stand-in planner that re-sends its answer as the lock-step planner does
        calls = []

        def poll(timeout, original=server.serve):
            calls.append(1)
            if len(calls) == 5:  # a viewer resumes: this very poll serves it
                resume.send(P.encode(P.Control(op="resume")))
            push.send(cmd)
            return original(timeout)

        server.serve = poll
        got = send_then_wait()
        assert got is not None and got.seq == server.episode.seq
        assert len(calls) >= 5  # nothing was taken while paused
        assert isinstance(P.decode(resume.recv(), expect=("control", "error")), P.Control)
    finally:
        push.close(0)
        resume.close(0)
        del server.serve
    assert not server.paused
    assert [e["op"] for e in _events(server, "control")] == ["pause", "resume"]


def test_control_messages_on_the_wire():
    msg = P.Control(
        op="move",
        object="cube_a",
        pos=np.array([1.0, 2.0, 3.0]),
        quat=np.array([1.0, 0.0, 0.0, 0.0]),
    )
    back = P.decode(P.encode(msg))
    assert back.object == "cube_a"
    np.testing.assert_array_equal(back.pos, [1, 2, 3])
    assert P.decode(P.encode(P.Control(op="pause"))).pos is None
    with pytest.raises(P.ProtocolError, match="needs 'object'"):
        P.decode(P.encode(P.Control(op="move", object="cube_a")))
    with pytest.raises(P.ProtocolError, match="expected shape \\[3\\]"):
        P.decode(P.encode(P.Control(op="move", object="cube_a", pos=np.zeros(2))))
    with pytest.raises(P.ProtocolError, match="non-zero quaternion"):
        P.decode(P.encode(P.Control(op="move", object="c", pos=np.zeros(3), quat=np.zeros(4))))
    with pytest.raises(P.ProtocolError, match="takes no object"):
        P.decode(P.encode(P.Control(op="reset", object="cube_a")))
    with pytest.raises(P.ProtocolError, match="expected one of"):
        P.decode(P.encode(P.Control(op="teleport")))


def test_diagnostics_name_each_trajectorys_mode():
    d = P.Diagnostics(
        seq=1,
        action="a",
        alternatives=[],
        mode_names=["push", "pull"],
        mode_weights=np.array([0.5, 0.5]),
        top=np.zeros((4, 3, 3)),
        plan_time=0.1,
        top_modes=np.array([0, 0, 1, 1]),
    )
    np.testing.assert_array_equal(P.decode(P.encode(d)).top_modes, [0, 0, 1, 1])
    d.top_modes = np.array([0, 1])
    with pytest.raises(P.ProtocolError, match="top_modes"):
        P.decode(P.encode(d))


def test_a_replay_reads_the_log_and_the_recorded_diagnostics(world):
    """What ``m3p2i view --log`` shows at a time: the logged state, the newest recorded
    diagnostics at or before it, the action running then."""
    import json

    from m3p2i.view import action_timeline, diagnostics_record, load_replay, metrics_text

    server = world("navigation")
    for action in ("go", "go", "wait", "wait"):
        server.episode.note_action(action)
        server.step(None)
    server.log.close()
    diag = P.Diagnostics(
        seq=2,
        action="wait",
        alternatives=["wait"],
        mode_names=["wait"],
        mode_weights=np.array([1.0]),
        top=np.ones((2, 3, 3)),
        plan_time=0.05,
        top_modes=np.array([0, 0]),
    )
    log_dir = server.log.path.parent
    (log_dir / "diagnostics.jsonl").write_text(json.dumps(diagnostics_record(diag)) + "\n")
    replay = load_replay(server.log.path)
    assert [s["seq"] for s in replay.steps] == [1, 2, 3, 4]
    assert [a for _, a in replay.actions] == ["go", "wait"]
    assert replay.diagnostics_at(1) is None  # none recorded yet then
    assert replay.diagnostics_at(3)["top_modes"] == [0, 0]  # the newest before
    dt = server.world.dt
    assert "**▶" in action_timeline(replay.actions, 2.5 * dt).splitlines()[1]
    assert "no summary" in metrics_text(replay.summary)  # the log was cut before its end


def test_the_panel_shows_the_identified_model_live_and_in_the_replay():
    """planner.model.variants: the estimate in Diagnostics.model reaches the side panel and
    the recorded diagnostics (for the replay); without it the panel says nothing of a model."""
    from m3p2i.view import PanelInfo, diagnostics_record

    diag = P.Diagnostics(
        seq=1,
        action="push",
        alternatives=["push"],
        mode_names=["push"],
        mode_weights=np.array([1.0]),
        top=np.ones((1, 2, 3)),
        plan_time=0.05,
        model={"mass.box": 1.4567, "gain.vel_x": 0.9},
    )
    rec = diagnostics_record(diag)
    assert rec["model"] == {"mass.box": 1.4567, "gain.vel_x": 0.9}
    text = PanelInfo(model=rec["model"]).markdown()
    assert "**identified model**" in text and "`mass.box` 1.46" in text
    assert "`gain.vel_x` 0.90" in text
    assert "model" not in diagnostics_record(dataclasses.replace(diag, model=None))
    assert "identified" not in PanelInfo().markdown()


def test_m3p2i_view_says_what_it_needs(tmp_path):
    from typer.testing import CliRunner

    from m3p2i.cli import app

    runner = CliRunner()
    result = runner.invoke(app, ["view"])
    assert result.exit_code == 2 and "give a SCENARIO for a live view, or --log" in result.output
    result = runner.invoke(app, ["view", "--log", str(tmp_path / "nowhere")])
    assert result.exit_code == 2 and "no episode log at" in result.output


def test_the_views_controls_pass_a_keyed_world(tmp_path):
    """Under CURVE (m3p2i run --keys) the view speaks with the planner's key pair: a world
    that allows only that key takes its ops."""
    import threading

    from m3p2i.keys import make_keys
    from m3p2i.view import ControlClient
    from planner_client.keys import load_planner_keys
    from server.keys import load_world_keys

    make_keys(tmp_path / "keys")
    port = free_port_block()
    server = WorldServer(
        load_scenario("pick_place"),
        Endpoints(port=port),
        tmp_path / "e.jsonl",
        keys=load_world_keys(tmp_path / "keys"),
    )
    client = ControlClient(
        zmq.Context.instance(),
        Endpoints(port=port),
        timeout=10,
        keys=load_planner_keys(tmp_path / "keys"),
    )
    replies = []
    sender = threading.Thread(
        target=lambda: replies.append(
            client.send(P.Control(op="move", object="cube_b", pos=np.array([0.2, 0.2, 1.1])))
        )
    )
    try:
        sender.start()
        for _ in range(200):
            server.serve(0.05)
            if replies:
                break
        sender.join(10)
    finally:
        server.log.close()
        server.close()
    assert replies == [(True, "move: done")]
    np.testing.assert_allclose(
        server.world.data.xpos[server.world.model.body("cube_b").id], [0.2, 0.2, 1.1]
    )
