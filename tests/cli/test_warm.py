"""Warm bench workers (m3p2i/warm.py): a server + planner pair kept across a case's
trials gives each seed the episode a fresh pair gives it, without the start-up; a seeded reset
is the world's, refused where it would overwrite a log; a failed trial takes its pair down."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from typer.testing import CliRunner

from m3p2i import bench as B
from m3p2i.launch import EpisodeLaunch, free_port_block
from m3p2i.warm import WarmPair
from server.app import ServerOptions, WorldServer
from server.cli import app as server_app
from server.evaluation import log_reader
from server.evaluation.metrics import MetricsEvaluator
from shared import protocol as P
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from tests.cli.test_view_control import _ask
from tests.episodes import with_max_time


def _trials(cases: list[tuple[str, str, list[int]]]) -> list[B.Trial]:
    out = []
    for label, scenario, seeds in cases:
        sc = load_scenario(scenario)
        case = B.BenchCase(label, "", str(scenario), len(seeds))
        out += [B.Trial(case, sc, MetricsEvaluator(sc), seed) for seed in seeds]
    return out


def _steps(path) -> list[tuple]:
    """What the world did at each step: time, state and the control that drove it."""
    return [
        (s["time"], s["qpos"], s["qvel"], s["ctrl"], s["action"])
        for s in log_reader.steps(log_reader.read_log(path))
    ]


def test_a_warm_pair_gives_each_seed_the_episode_of_a_fresh_pair(tmp_path):
    # an active-inference task (beliefs, its own clock) and fixed modes; 3 s of the battery
    # run is enough for its warm start, AIP state and random stream to matter
    battery = with_max_time("battery_recharge", 3.0, tmp_path)
    warm = _trials([("navigation", "navigation", [0, 1, 2]), ("battery", battery, [0, 1])])
    fresh = _trials([("navigation", "navigation", [1, 2]), ("battery", battery, [1])])
    runs = {}

    def bench(name, todo, fresh_pairs):
        opts = B.BenchOptions(out_dir=tmp_path / name, workers=1, timeout=300, fresh=fresh_pairs)
        results = B.ResultsFile(tmp_path / name / "results.csv")
        runs[name] = B.run_trials(todo, opts, results)

    # lock-step episodes do not depend on the load: both benches at once, one core each
    threads = [
        threading.Thread(target=bench, args=args)
        for args in (("warm", warm, False), ("fresh", fresh, True))
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert runs == {"warm": True, "fresh": True}
    rows = {
        name: {
            (r["case"], r["seed"]): r for r in B.ResultsFile(tmp_path / name / "results.csv").rows()
        }
        for name in runs
    }
    assert all(not r["reason"] for r in rows["warm"].values()), rows["warm"]
    # one pair per case, not one per trial: the later seeds really ran warm
    for case in ("navigation", "battery"):
        assert len(list((tmp_path / "warm" / "logs" / case / "pairs").iterdir())) == 1
    assert (
        "new episode (seed 2)"
        in (tmp_path / "warm/logs/navigation/seed-002/planner.log").read_text()
    )
    for key, row in rows["fresh"].items():
        assert not row["reason"]
        same = rows["warm"][key]
        for column in ("status", "position_error", "time", "steps", "initial"):
            assert same[column] == row[column], (key, column)
        assert _steps(tmp_path / "warm" / same["log"]) == _steps(tmp_path / "fresh" / row["log"]), (
            key
        )
        # the warm trial's time is the episode's, not the processes' start-up
        assert float(same["trial_wall"]) - float(same["wall_time"]) < float(
            row["trial_wall"]
        ) - float(row["wall_time"])


def test_a_trial_that_fails_takes_its_pair_down_and_the_next_starts_afresh(tmp_path):
    launch = EpisodeLaunch(
        scenario="navigation",
        run_dir=tmp_path / "pair",
        threads=2,
        log=str(tmp_path / "seed-{seed:03d}" / "episode.jsonl"),
    )
    pair = WarmPair(launch)
    try:
        late = pair.run(0, timeout=0.2)
        assert late.reason == "timeout" and not pair.alive
        ok = pair.run(1, timeout=300)
        assert ok.reason == "" and ok.summary["status"] == "success" and pair.alive
        assert log_reader.header(log_reader.read_log(ok.log_path))["seed"] == 1
        assert (tmp_path / "seed-001" / "planner.log").is_file()
    finally:
        pair.close()
    with pytest.raises(ValueError, match="seed"):
        WarmPair(EpisodeLaunch(scenario="navigation", run_dir=tmp_path, log="x.jsonl"))


@pytest.fixture
def kept_world(tmp_path):
    server = WorldServer(
        load_scenario("navigation"),
        Endpoints(port=free_port_block()),
        tmp_path / "seed-{seed}.jsonl",
        ServerOptions(keep_serving=True),
        seed=3,
    )
    yield server
    server.log.close()
    server.close()


def test_a_kept_world_begins_the_seeds_episode_on_a_seeded_reset(kept_world, tmp_path):
    first = kept_world.episode.session
    assert kept_world.log.path == tmp_path / "seed-3.jsonl"
    assert isinstance(_ask(kept_world, P.Control(op="reset", seed=7)), P.Control)
    assert not kept_world.running  # the running episode ends ...
    kept_world.serve_episode()
    kept_world.next_episode()  # ... as run() does, and the next begins
    assert kept_world.episode.session != first and kept_world.episode.seq == 0
    assert log_reader.summary(log_reader.read_log(tmp_path / "seed-3.jsonl"))["status"] == "stopped"
    assert log_reader.header(log_reader.read_log(tmp_path / "seed-7.jsonl"))["seed"] == 7
    fresh = WorldServer(
        load_scenario("navigation"),
        Endpoints(port=free_port_block()),
        tmp_path / "fresh.jsonl",
        seed=7,
    )
    try:  # the kept world's start for seed 7 is a fresh world's
        np.testing.assert_array_equal(kept_world.world.data.qpos, fresh.world.data.qpos)
    finally:
        fresh.log.close()
        fresh.close()


def test_a_seeded_reset_is_refused_by_a_world_serving_one_episode(tmp_path):
    server = WorldServer(
        load_scenario("navigation"), Endpoints(port=free_port_block()), tmp_path / "episode.jsonl"
    )
    try:
        reply = _ask(server, P.Control(op="reset", seed=4))
        assert isinstance(reply, P.Error) and "--keep-serving" in reply.reason
        assert server.running
    finally:
        server.log.close()
        server.close()


def test_reset_seeds_on_the_wire():
    assert P.decode(P.encode(P.Control(op="reset", seed=5))).seed == 5
    assert P.decode(P.encode(P.Control(op="reset"))).seed is None
    with pytest.raises(P.ProtocolError, match="takes no seed"):
        P.decode(P.encode(P.Control(op="pause", seed=5)))
    with pytest.raises(P.ProtocolError, match="0 <= seed"):
        P.decode(P.encode(P.Control(op="reset", seed=-1)))
    welcome = P.Welcome(
        scenario="s", scenario_hash="h", mode="lockstep", dt=0.01, nu=2, session="a", seed=9
    )
    assert P.decode(P.encode(welcome)).seed == 9


def test_keep_serving_needs_a_log_per_seed():
    result = CliRunner().invoke(server_app, ["--scenario", "navigation", "--keep-serving"])
    assert result.exit_code == 2 and "{seed}" in result.output
