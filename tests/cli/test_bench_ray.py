"""``m3p2i bench --ray``: on a local Ray instance (2 CPUs, one ``ray.init`` shared by the module)
a bench writes the same results rows as the local pool (lock-step: same seeds, same outcomes)
and the same log files; a task whose worker is killed mid-trial, or one past its time-out, is
a failure row with its reason and the bench finishes."""

from __future__ import annotations

import csv
import os
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from m3p2i import bench as B
from m3p2i.cli import app
from shared.scenario import SCENARIO_DIR

ray = pytest.importorskip("ray", reason="needs the cluster extra: pip install 'm3p2i[cluster]'")
from m3p2i import bench_ray as BR  # noqa: E402  (needs ray)

pytestmark = pytest.mark.slow

# what a lock-step trial repeats exactly for its seed on one machine (not the wall-clock columns)
DETERMINISTIC = (
    "case",
    "variant",
    "scenario",
    "scenario_hash",
    "seed",
    "success",
    "status",
    "reason",
    "position_error",
    "orientation_error",
    "collisions",
    "time",
    "steps",
    "initial",
    "log",
    "mode",
    "overrides",
)


@pytest.fixture(scope="module")
def local_ray():
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("RAY_process_group_cleanup_enabled", "1")  # as bench_ray.connect
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield BR.connect(None, 2)
    ray.shutdown()


def scenario(tmp_path, name: str, max_time: float, reachable: bool = True) -> str:
    """navigation, cheap (50 samples, horizon 10); unreachable: a success test that never
    holds, so the episode lasts ``max_time``."""
    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["name"] = name
    raw["planner"].update(samples=50, horizon=10)
    raw["episode"]["max_time"] = max_time
    if not reachable:
        raw["episode"]["success"] = [
            {"near": {"a": "robot", "b": "goal", "within": 0.0, "axes": "xy"}}
        ]
    (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(raw))
    return f"{name}.yaml"


def write_bench(tmp_path, cases) -> Path:
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump({"timeout": 120, "cases": cases}))
    return path


def rows(out: Path) -> list[dict[str, str]]:
    return sorted(
        csv.DictReader((out / "results.csv").open()), key=lambda r: (r["overrides"], int(r["seed"]))
    )


def test_ray_bench_writes_the_local_pools_rows(tmp_path, local_ray):
    nav = scenario(tmp_path, "nav", 4.0)
    bench = write_bench(
        tmp_path, [{"case": "nav", "variant": "m3p2i", "scenario": nav, "trials": 4}]
    )
    runner = CliRunner()
    common = ["bench", str(bench), "--workers", "2"]
    local = runner.invoke(app, [*common, "--out", str(tmp_path / "local")])
    assert local.exit_code == 0, local.output
    on_ray = runner.invoke(app, [*common, "--out", str(tmp_path / "ray"), "--ray"])
    assert on_ray.exit_code == 0, on_ray.output
    assert "Ray: local instance, 1 node(s), 2 CPUs" in on_ray.output
    a, b = rows(tmp_path / "local"), rows(tmp_path / "ray")
    assert [r["seed"] for r in a] == ["0", "1", "2", "3"] and any(r["success"] == "1" for r in a)
    assert [[r[k] for k in DETERMINISTIC] for r in b] == [[r[k] for k in DETERMINISTIC] for r in a]
    for r in b:  # the logs came back to the driver, where the pool puts them
        log, there = tmp_path / "ray" / r["log"], tmp_path / "local" / r["log"]
        assert len(log.read_text().splitlines()) == len(there.read_text().splitlines())
        assert (log.parent / "planner.log").is_file() and (log.parent / "server.log").is_file()
    # resuming on Ray skips what the file has, as the pool does
    again = runner.invoke(app, [*common, "--out", str(tmp_path / "ray"), "--ray"])
    assert (
        again.exit_code == 0 and "4 already in" in again.output and len(rows(tmp_path / "ray")) == 4
    )


def _server_of(scenario_name: str) -> list[tuple[int, int]]:
    """(pid, parent pid) of the world servers running ``scenario_name`` on this machine."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0")
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        if b"server" in cmd and any(scenario_name.encode() in c for c in cmd):
            found.append((int(entry.name), int(stat.rsplit(")", 1)[1].split()[1])))
    return found


def _planner_of(scenario_name: str) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0") if entry.name.isdigit() else []
        except OSError:
            continue
        if b"planner_client" in cmd and any(scenario_name.encode() in c for c in cmd):
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    """Running, not a zombie waiting for its parent to read its status."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _plan(tmp_path, cases, timeout: float):
    cfg = B.load_bench(write_bench(tmp_path, cases))
    ready, _ = B.select_cases(cfg)
    opts = B.BenchOptions(out_dir=tmp_path / "out", workers=2, timeout=timeout)
    _, todo = B.plan_trials(ready, cfg, opts, set())
    return todo, opts, B.ResultsFile(opts.out_dir / "results.csv")


def test_a_killed_task_is_a_failure_row_and_the_bench_finishes(tmp_path, local_ray):
    endless = scenario(tmp_path, "endless_kill", 600.0, reachable=False)  # minutes of episode
    nav = scenario(tmp_path, "nav", 4.0)
    todo, opts, results = _plan(
        tmp_path,
        [
            {"case": "endless", "scenario": endless, "trials": 1},
            {"case": "nav", "scenario": nav, "trials": 1},
        ],
        300.0,
    )
    outcome = {}
    bench = threading.Thread(
        target=lambda: outcome.update(ok=BR.run_trials(todo, opts, results, local_ray, 1)),
        daemon=True,
    )
    bench.start()
    killed, orphans = None, []
    try:
        deadline = time.monotonic() + 90
        while killed is None and time.monotonic() < deadline:
            servers = _server_of("endless_kill.yaml")
            if servers:  # the Ray worker running the trial: kill it
                killed = servers[0][1]
                time.sleep(1.0)  # mid-trial: the episode is under way
                orphans = [servers[0][0], *_planner_of("endless_kill.yaml")]
                os.kill(killed, signal.SIGKILL)
            time.sleep(0.2)
        assert killed is not None, "the endless trial never started"
        bench.join(120)
        assert not bench.is_alive() and outcome["ok"]
        # Ray takes the dead worker's process group, the trial's two processes, with it
        deadline = time.monotonic() + 30
        while (
            any(Path(f"/proc/{pid}").exists() and _alive(pid) for pid in orphans)
            and time.monotonic() < deadline
        ):
            time.sleep(0.2)
        assert not [pid for pid in orphans if _alive(pid)], "the trial's processes outlived it"
    finally:
        for pid in orphans:  # its server and planner outlive the worker
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    got = {r["case"]: r for r in results.rows()}
    assert got["endless"]["success"] == "0" and got["endless"]["status"] == "failure"
    assert got["endless"]["reason"].startswith("the Ray task failed:"), got["endless"]
    assert got["nav"]["reason"] == "" and got["nav"]["status"] in ("success", "timeout")
    assert (opts.out_dir / got["nav"]["log"]).is_file()


def test_a_task_past_its_time_out_is_cancelled_and_recorded(tmp_path, local_ray, monkeypatch):
    endless = scenario(tmp_path, "endless_cancel", 600.0, reachable=False)
    # the driver gives up 3 s into the trial, long before the trial's own 60 s time-out
    monkeypatch.setattr(BR, "GRACE", -57.0)
    monkeypatch.setattr(BR, "FORCE_AFTER", 5.0)
    todo, opts, results = _plan(
        tmp_path, [{"case": "endless", "scenario": endless, "trials": 1}], 60.0
    )
    started = time.monotonic()
    assert BR.run_trials(todo, opts, results, local_ray, 1)
    assert time.monotonic() - started < 45
    (row,) = results.rows()
    assert row["reason"] == "timeout: the Ray task ran past 60 s + -57 s and was cancelled"
    assert row["success"] == "0"
    # the polite cancel let the trial stop its processes
    deadline = time.monotonic() + 20
    while (
        _server_of("endless_cancel.yaml") or _planner_of("endless_cancel.yaml")
    ) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _server_of("endless_cancel.yaml") and not _planner_of("endless_cancel.yaml")
