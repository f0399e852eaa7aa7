"""Bad input never crashes anything: absurd values from a peer, a scenario file or a browser are
refused with a reason (or played safely), never an exception that ends a process."""

from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar

import msgpack
import numpy as np
import pytest

from planner_client.timing import playing
from server.plan_player import PlanPlayer
from shared import protocol as P
from shared.timed_plan import TimedPlan

V = P.PROTOCOL_VERSION


def _plan_command(t0: float, dt: float, knots: int = 3) -> bytes:
    arr = lambda a: P.encode_array(np.asarray(a, dtype=float))  # noqa: E731
    return msgpack.packb(
        {
            "type": "command",
            "v": V,
            "session": "s",
            "seq": 1,
            "ctrl": arr([0.0, 0.0]),
            "plan_ctrl": arr(np.zeros((knots, 2))),
            "plan_t0": t0,
            "plan_dt": dt,
        },
        use_bin_type=True,
    )


# ---------------------------------------------------------------- 1: a plan's indexing is total


@pytest.mark.parametrize(
    "t0, dt, t",
    [
        (0.0, 5e-324, 0.02),  # the reported one: (t - t0) / dt overflows to inf
        (0.0, 5e-324, 1e308),
        (-1e308, 1e-3, 1e308),  # t - t0 is inf
        (0.0, 1e308, 1e308),
        (0.0, math.inf, math.inf),  # a held command at t = inf: inf / inf is NaN
        (0.0, 0.01, math.nan),
    ],
)
def test_a_plan_answers_every_time_without_raising(t0, dt, t):
    plan = TimedPlan(t0, dt, np.zeros((3, 2)))
    got = plan.at(t)
    assert got is None or got.shape == (2,)
    player = PlanPlayer()
    player.receive(plan)
    player.control(t)
    playing([plan], t)


def test_an_index_beyond_the_plan_is_past_its_end():
    plan = TimedPlan(0.0, 5e-324, np.zeros((3, 2)))
    assert plan.index(0.0) == 0
    assert plan.index(0.02) is None


@pytest.mark.parametrize(
    "t0, dt, reason",
    [
        (0.0, 5e-324, "plan_dt"),
        (0.0, 1e-9, "plan_dt"),
        (1e308, 1e308, "finite"),
    ],
)
def test_a_command_with_an_absurd_plan_is_refused_with_the_reason(t0, dt, reason):
    with pytest.raises(P.ProtocolError) as info:
        P.decode(_plan_command(t0, dt), expect="command")
    assert reason in str(info.value)


def test_a_sane_plan_still_decodes():
    cmd = P.decode(_plan_command(12.5, 0.01), expect="command")
    assert cmd.has_plan and cmd.plan_dt == 0.01


# ---------------------------------------------------------------- 2: .inf and .nan in a file

NON_FINITE = [
    # the repros, in the old name of faults: (read as faults:, and named so)
    ("hardware: {actuation_delay_ms: .inf}\n", "faults.actuation_delay_ms"),
    ("hardware: {state_delay_ms: .nan}\n", "faults.state_delay_ms"),
    ("faults: {position_noise_m: .nan}\n", "faults.position_noise_m"),
    ("planner: {delays: {actuation_ms: .inf}}\n", "planner.delays.actuation_ms"),
    ("planner: {delays: {max_ms: -.inf}}\n", "planner.delays.max_ms"),
]


def _based_on_navigation(tmp_path, extra: str):
    path = tmp_path / "odd.yaml"
    path.write_text(f"base: navigation\nname: odd\n{extra}")
    return path


# the old section name and a nested key through both processes' checks (~2.5 s each); every
# case through the loader: test_the_loader_refuses_non_finite_numbers
@pytest.mark.parametrize("extra, key", NON_FINITE[::3], ids=[k for _, k in NON_FINITE[::3]])
def test_m3p2i_check_refuses_non_finite_numbers_naming_file_and_key(tmp_path, extra, key):
    from typer.testing import CliRunner

    from m3p2i.cli import app

    path = _based_on_navigation(tmp_path, extra)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    assert f"{path}: {key}: must be a finite number" in result.output


@pytest.mark.filterwarnings("ignore:hardware.*is deprecated:FutureWarning")  # test_faults.py's
def test_the_loader_refuses_non_finite_numbers(tmp_path):
    from shared.config import ConfigError
    from shared.scenario import load_scenario

    for extra, key in NON_FINITE:
        with pytest.raises(ConfigError) as info:
            load_scenario(_based_on_navigation(tmp_path, extra))
        assert key in str(info.value) and "finite" in str(info.value)


def test_m3p2i_run_refuses_an_infinite_delay_before_starting_anything(tmp_path):
    from typer.testing import CliRunner

    from m3p2i.cli import app

    run_dir = tmp_path / "run"
    path = _based_on_navigation(tmp_path, "planner: {delays: {actuation_ms: .inf}}\n")
    result = CliRunner().invoke(app, ["run", str(path), "--run-dir", str(run_dir)])
    assert result.exit_code == 2, result.output
    assert "planner.delays.actuation_ms: must be a finite number" in result.output
    assert not run_dir.exists()


PANDA_RESULTS = Path(__file__).resolve().parents[2] / "docs" / "bench" / "panda" / "results.csv"
OUT_OF_RANGE = [
    ("m3p2i", "--seed", "-1"),
    ("m3p2i", "--seed", "4294967296"),  # a seed travels in the welcome and a reset: < 2**32
    ("server", "--seed", "-1"),
    ("planner", "--seed", "4294967296"),
    ("m3p2i", "--port", "65533"),  # the world's ports are PORT..PORT+3
    ("server", "--port", "70000"),
    ("planner", "--port", "0"),
    ("m3p2i", "--timeout", "0"),
    ("server", "--command-timeout", "-1"),
    ("planner", "--threads", "-1"),
    ("planner", "--server-timeout", "0"),
    ("view", "--duration", "-1"),
    ("bench", "--workers", "-1"),  # ran no trial and exited 0
    ("bench", "--seed", "4294967295"),  # its second trial's seed would be 2**32
    ("server", "--realtime-factor", "inf"),
    ("report", "--check", None),  # without --update it checked nothing and passed
]


@pytest.mark.parametrize("cli, option, value", OUT_OF_RANGE)
def test_an_option_out_of_its_range_is_refused_before_starting_anything(
    tmp_path, cli, option, value
):
    """A negative seed crashed the world's seeding after the launcher had started both
    processes; port 70000 served on a port nobody could reach, a negative command time-out
    held a real-time robot still forever: each is now a usage error naming the option."""
    from typer.testing import CliRunner

    from m3p2i.cli import app as m3p2i_app
    from planner_client.cli import app as planner_app
    from server.cli import app as server_app

    run_dir = tmp_path / "run"
    app, args = {
        "m3p2i": (m3p2i_app, ["run", "navigation", "--run-dir", str(run_dir)]),
        "server": (server_app, ["--scenario", "navigation", "--log", str(run_dir / "e.jsonl")]),
        "planner": (planner_app, ["--scenario", "navigation"]),
        "view": (m3p2i_app, ["view", "navigation"]),
        "bench": (m3p2i_app, ["bench", "paper", "--quick", "--out", str(run_dir)]),
        "report": (m3p2i_app, ["report", str(PANDA_RESULTS)]),
    }[cli]
    result = CliRunner().invoke(app, [*args, option, *([value] if value else [])])
    assert result.exit_code == 2, result.output
    assert option in result.output
    assert not run_dir.exists()


@pytest.mark.parametrize(
    "args, said",
    [
        (["--out", "clip.txt"], "--out clip.txt: expected a .gif or .mp4 file"),
        (["--out", "clip.gif", "--fps", "0"], "--fps"),  # divided by: a ZeroDivisionError
        (["--out", "clip.gif", "--width", "-5"], "--width"),  # failed after the episode
    ],
)
def test_m3p2i_record_refuses_what_it_could_not_write_before_the_episode(tmp_path, args, said):
    from typer.testing import CliRunner

    from m3p2i.cli import app

    run_dir = tmp_path / "run"
    result = CliRunner().invoke(app, ["record", "navigation", "--run-dir", str(run_dir), *args])
    assert result.exit_code == 2, result.output
    assert said in result.output
    assert not run_dir.exists()


def test_a_world_whose_ports_are_taken_says_so_and_leaves_no_log(tmp_path):
    """Another process on one of the world's four ports: a usage error naming the address
    (it was a ZMQError traceback and exit 1, an unsuccessful episode's code)."""
    import socket

    from typer.testing import CliRunner

    from server.cli import app
    from tests.helpers import free_port_block

    port = free_port_block()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port + 2))  # the command port
        taken.listen()
        log = tmp_path / "episode.jsonl"
        args = ["--scenario", "navigation", "--port", str(port), "--log", str(log)]
        result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert f"cannot serve on tcp://127.0.0.1:{port + 2}: Address already in use" in result.output
    assert not log.exists()


@pytest.mark.parametrize(
    "flags, said",
    [
        (["--port", "{port}"], "--port {port}: port {taken} is taken"),
        (["--view", "--view-port", "{taken}"], "--view-port {taken}: port {taken} is taken"),
        (["--view-port", "{free}"], "--view-port serves the page of --view"),
    ],
)
def test_m3p2i_run_refuses_ports_it_could_not_use_before_starting_anything(tmp_path, flags, said):
    """A world would fail to bind a taken port; a view moves to the next free port while the
    launcher waited on the one asked for (then gave up after 120 s)."""
    import socket

    from typer.testing import CliRunner

    from m3p2i.cli import app
    from tests.helpers import free_port_block

    port = free_port_block()
    names = {"port": port, "taken": port + 1, "free": free_port_block(count=1)}
    run_dir = tmp_path / "run"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port + 1))
        taken.listen()
        args = ["run", "navigation", "--run-dir", str(run_dir)]
        result = CliRunner().invoke(app, [*args, *(f.format(**names) for f in flags)])
    assert result.exit_code == 2, result.output
    assert said.format(**names) in result.output
    assert not run_dir.exists()


@pytest.mark.parametrize(
    "args, said",
    [
        (["--mode", "realtime", "--plan-every", "3"], "--plan-every 3: only a lock-step world"),
        (["--realtime-factor", "2"], "--realtime-factor 2: only a real-time world"),
    ],
)
def test_m3p2i_server_refuses_an_option_of_the_other_mode(tmp_path, args, said):
    """As m3p2i run and the bench do: the world would have ignored it."""
    from typer.testing import CliRunner

    from server.cli import app

    log = tmp_path / "episode.jsonl"
    result = CliRunner().invoke(app, ["--scenario", "navigation", "--log", str(log), *args])
    assert result.exit_code == 2, result.output
    assert said in result.output
    assert not log.exists()


def test_m3p2i_view_refuses_live_options_with_a_replay():
    """--record, --keys, --host, --port, --public-controls and --replay-after were ignored by a
    replay (--log), so a user asking for a recording got none."""
    from typer.testing import CliRunner

    from m3p2i.cli import app

    args = ["view", "--log", str(PANDA_RESULTS.parent), "--record", "x.jsonl", "--port", "6000"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "--port, --record: live view only" in result.output


# ---------------------------------------------------------------- 3: only the view's own page


def _ws_open(port: int, origin: str | None, host: str | None = None) -> str:
    """A websocket handshake with viser's subprotocol, as a browser page at ``origin`` (asking
    for ``host``) would send it: 'accepted' (and the scene's first message arrived) or the
    refusal."""
    import base64
    import os
    import socket

    import viser

    key = base64.b64encode(os.urandom(16)).decode()
    lines = [
        "GET / HTTP/1.1",
        f"Host: {host or f'127.0.0.1:{port}'}",
        "Upgrade: websocket",
        "Connection: Upgrade",
        f"Sec-WebSocket-Key: {key}",
        "Sec-WebSocket-Version: 13",
        f"Sec-WebSocket-Protocol: viser-v{viser.__version__}",
    ]
    if origin is not None:
        lines.append(f"Origin: {origin}")
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        reply = b""
        while b"\r\n\r\n" not in reply:
            chunk = sock.recv(65536)
            assert chunk, reply
            reply += chunk
        status = int(reply.split(b" ", 2)[1])
        if status != 101:
            return f"refused {status}"
        _head, _, rest = reply.partition(b"\r\n\r\n")
        if not rest:
            rest = sock.recv(65536)  # the scene's first websocket frame
        return "accepted" if rest else "accepted, nothing sent"


@pytest.fixture
def live_view():
    pytest.importorskip("viser")
    from m3p2i.launch import free_port_block
    from m3p2i.view import LiveView
    from shared.endpoints import Endpoints
    from shared.scenario import load_scenario

    views = []

    def make(bind: str = "127.0.0.1", **kw) -> LiveView:
        view = LiveView(
            load_scenario("navigation"),
            Endpoints(port=free_port_block()),
            bind,
            free_port_block(count=1),
            **kw,
        )
        views.append(view)
        return view

    yield make
    for view in views:
        view.close()


def test_a_page_of_another_origin_cannot_open_the_views_websocket(live_view):
    port = live_view().server.get_port()
    assert _ws_open(port, "http://evil.example") == "refused 403"
    assert (
        _ws_open(port, f"http://evil.example:{port}", host=f"evil.example:{port}") == "refused 403"
    )  # DNS rebinding
    assert _ws_open(port, "null") == "refused 403"  # a sandboxed page
    assert _ws_open(port, f"http://127.0.0.1:{port}") == "accepted"
    assert _ws_open(port, f"http://localhost:{port}", host=f"localhost:{port}") == "accepted"
    assert _ws_open(port, None) == "accepted"  # not a browser


def test_a_public_view_accepts_its_machines_names_and_addresses_only():
    from m3p2i.view import OriginPolicy

    public = OriginPolicy(public=True, names=frozenset({"lab-pc"}))
    for host in ("lab-pc:8080", "192.168.1.20:8080", "[fe80::1]:8080", "localhost:8080"):
        assert public.refusal(f"http://{host}", host) is None, host
    assert public.refusal("http://evil.example:8080", "evil.example:8080")  # DNS rebinding
    assert public.refusal("http://evil.example", "lab-pc:8080")
    local = OriginPolicy()
    assert local.refusal("http://192.168.1.20:8080", "192.168.1.20:8080")
    assert local.refusal("http://[::1]:8080", "[::1]:8080") is None


# ---------------------------------------------------------------- 4, 5: m3p2i view's options


class _FakeView:
    """Stands in for LiveView in the command line's tests: what it was given."""

    made: ClassVar[list[dict]] = []

    def __init__(self, *args, **kwargs):
        _FakeView.made.append({"args": args, **kwargs})
        self.url = "http://127.0.0.1:1/"

    def serve(self, duration=None):
        pass

    def close(self):
        pass


def _view_cli(monkeypatch, *argv: str):
    from typer.testing import CliRunner

    from m3p2i import view as V
    from m3p2i.cli import app

    monkeypatch.setattr(V, "LiveView", _FakeView)
    _FakeView.made.clear()
    result = CliRunner().invoke(app, ["view", "navigation", *argv])
    assert result.exit_code == 0, result.output
    (made,) = _FakeView.made
    return made


def test_m3p2i_view_keys_needs_only_the_planners_pair(monkeypatch, tmp_path):
    import shutil

    from m3p2i.keys import make_keys

    make_keys(tmp_path / "keys")
    shutil.rmtree(tmp_path / "keys" / "world")  # a planner machine holds only DIR/planner
    made = _view_cli(monkeypatch, "--keys", str(tmp_path / "keys"))
    own = (tmp_path / "keys" / "planner" / "planner.key").read_bytes()
    assert made["keys"].own.public.decode() in own.decode()


def test_a_public_view_has_no_controls_unless_asked(monkeypatch):
    assert _view_cli(monkeypatch)["controls"] is True
    assert _view_cli(monkeypatch, "--public")["controls"] is False
    assert _view_cli(monkeypatch, "--public", "--public-controls")["controls"] is True


@pytest.mark.filterwarnings("error::DeprecationWarning")  # viser's drag API as it now stands
def test_a_handle_dragged_in_the_page_moves_its_object_once_let_go(live_view):
    """A drag's phases as viser reports them to the handle's callbacks: while it is held the
    world's states no longer place the handle; on release one ``move`` goes to the world, where
    the handle was let go."""
    import viser

    view = live_view()
    sent = []
    view.control.send = lambda msg: sent.append(msg) or (True, "ok")
    name, (_, handle) = next(iter(view.gizmos.items()))

    def drag(phase: str) -> None:
        event = viser.TransformControlsEvent(
            client=None, client_id=None, target=handle, phase=phase
        )
        for callback in handle._impl_aux.update_cb:  # viser's own list of on_update callbacks
            callback(event)

    drag("start")
    handle.position = (0.3, -0.2, 0.1)
    drag("update")
    assert handle.dragging and sent == []
    drag("end")
    assert not handle.dragging
    assert [(m.op, m.object) for m in sent] == [("move", name)]
    np.testing.assert_allclose(sent[0].pos, [0.3, -0.2, 0.1])


def test_a_view_without_controls_shows_no_buttons_and_sends_nothing(live_view):
    from m3p2i.view import LiveView

    view: LiveView = live_view(controls=False)
    assert view.buttons == {} and view.gizmos == {}
    assert set(live_view().buttons) == {"Pause", "Resume", "Reset"}
    sent = []
    view.control.send = lambda msg: sent.append(msg) or (True, "ok")
    assert view._send(P.Control(op="pause")) is False and not sent


# ---------------------------------------------------------------- 10: found by the fuzzer


@pytest.mark.parametrize(
    "extra, key",
    [
        ("world: {timestep: 5.0e-324}\n", "world.timestep"),
        ("planner: {timestep: 5.0e-324}\n", "planner.timestep"),
        ("planner: {timestep: 1.0e+300}\n", "planner.timestep"),
    ],
)
def test_an_absurd_timestep_is_refused_naming_the_key(tmp_path, extra, key):
    # found by tests/shared/test_fuzz.py: world.timestep 5e-324 made
    # planner.timestep / world.timestep inf, and round(inf) raised OverflowError out of the loader
    import yaml

    from shared.config import ConfigError
    from shared.scenario import SCENARIO_DIR, load_scenario

    raw = _based_on_navigation(tmp_path, extra)
    if extra.startswith("world"):  # world: a whole section, not merged with the base's
        data = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
        data["world"]["timestep"] = 5e-324
        data.setdefault("planner", {})["timestep"] = 0.05
        raw.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as info:
        load_scenario(raw)
    assert f"{raw}: {key}" in str(info.value)
