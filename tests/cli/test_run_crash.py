"""``m3p2i run`` notices a process that died: a planner that fails (an uncaught error, e.g. a
user's cost term that raises) exits 4, and the run ends at once, non-zero, naming the planner and
the last lines of its log, with the episode's log and summary still written; a planner gone for
good while the world runs, or a world that dies, is noticed too."""

from __future__ import annotations

import sys

import pytest
from typer.testing import CliRunner

from m3p2i import launch as L
from m3p2i.cli import app
from server.evaluation import log_reader
from tests.user_folder import reach, user_folder

# the lab's term: a distance that works for 20 calls, then raises mid-episode (so that
# a check evaluating each term once at start-up still passes it)
BREAKS_LATER = """
from dataclasses import dataclass

from planner_client.costs import CostTerm, register
from planner_client.sensors import SensorRequest

CALLS = [0]


@register("breaks_later")
@dataclass
class BreaksLater(CostTerm):
    a: str
    b: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), b=ctx.frame(s, "b"))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.b)]

    def __call__(self, batch):
        CALLS[0] += 1
        if CALLS[0] > 20:
            raise RuntimeError("the lab's term broke on call %d" % CALLS[0])
        pa, pb = (batch.get(r) for r in self.requests)
        return ((pa - pb) ** 2).sum(-1)
"""


@pytest.mark.slow
def test_m3p2i_run_ends_at_once_naming_a_planner_whose_cost_term_raised(tmp_path):
    terms = [{"term": "breaks_later", "a": "robot", "b": "target", "weight": 1.0}]
    path = user_folder(tmp_path, scenario=reach(terms=terms, plugins=["breaks_later"]))
    (path.parent / "breaks_later.py").write_text(BREAKS_LATER)
    run_dir = tmp_path / "run"
    # the time-out only bounds a regression (which waited it out): the crash ends the run first
    result = CliRunner().invoke(
        app, ["run", str(path), "--run-dir", str(run_dir), "--timeout", "240"]
    )
    out = result.output
    assert result.exit_code == 1, out
    assert "no outcome within" not in out, out
    assert "error: the planner failed: RuntimeError: the lab's term broke on call 21" in out
    assert f"error: the planner exited with code 4; the last lines of {run_dir}" in out
    assert "  RuntimeError: the lab's term broke on call 21" in out  # the traceback's last line
    summary = log_reader.summary(log_reader.read_log(run_dir / "episode.jsonl"))
    assert summary is not None and summary["status"] == "stopped", summary


def _fake(monkeypatch, server: str, planner: str) -> None:
    """The launcher starts these two Python snippets instead of the world and the planner."""
    cmds = {"server": [sys.executable, "-c", server], "planner": [sys.executable, "-c", planner]}
    monkeypatch.setattr(L.EpisodeLaunch, "commands", lambda self, port: cmds)


def test_a_planner_gone_while_the_world_still_runs_ends_the_run(tmp_path, monkeypatch):
    # exit 1 is an episode's end; a world that then never ends is waiting for a dead planner
    _fake(monkeypatch, "import time; time.sleep(120)", "print('bye'); raise SystemExit(1)")
    monkeypatch.setattr(L, "WORLD_ENDS_WITHIN", 0.5)
    run = L.run_episode(L.EpisodeLaunch(scenario="navigation", run_dir=tmp_path, timeout=60))
    assert run.reason == "planner exited with code 1" and L.died(run.reason) == "planner"
    assert L.log_tail(tmp_path / "planner.log") == ["bye"]


def test_a_world_that_dies_is_named(tmp_path, monkeypatch):
    _fake(monkeypatch, "raise SystemExit(2)", "import time; time.sleep(120)")
    run = L.run_episode(L.EpisodeLaunch(scenario="navigation", run_dir=tmp_path, timeout=60))
    assert run.reason == "server exited with code 2" and L.died(run.reason) == "server"


def test_a_world_that_fails_before_its_episode_is_named_though_it_exits_1(tmp_path, monkeypatch):
    # exit 1 is also an episode's end: without a summary in the log it is the world's failure
    world = "print('RuntimeError: no driver'); raise SystemExit(1)"
    _fake(monkeypatch, world, "import time; time.sleep(120)")
    run = L.run_episode(L.EpisodeLaunch(scenario="navigation", run_dir=tmp_path, timeout=60))
    assert run.reason == "server exited with code 1 without an episode summary"
    assert L.died(run.reason) == "server"
    assert L.log_tail(tmp_path / "server.log") == ["RuntimeError: no driver"]


def test_a_reused_run_folder_never_reports_the_earlier_episode(tmp_path, monkeypatch):
    # the earlier episode's log, a success: a world that fails at once must not pass for it
    earlier = '{"kind": "header"}\n{"kind": "summary", "status": "success", "time": 1.0}\n'
    (tmp_path / "episode.jsonl").write_text(earlier)
    _fake(monkeypatch, "raise SystemExit(1)", "import time; time.sleep(120)")
    run = L.run_episode(L.EpisodeLaunch(scenario="navigation", run_dir=tmp_path, timeout=60))
    assert run.summary is None
    assert run.reason == "server exited with code 1 without an episode summary"
    assert (tmp_path / "episode.jsonl").read_text() == earlier  # kept, not deleted


def test_the_report_names_the_dead_process_and_its_log_tail(tmp_path, capsys):
    from m3p2i.cli import _report_run

    (tmp_path / "planner.log").write_text(
        "INFO planning\nTraceback (most recent call last):\n  ...\nValueError: boom\n"
        "error: the planner failed: ValueError: boom\n"
    )
    run = L.EpisodeRun(tmp_path / "episode.jsonl", None, "planner exited with code 4", 1.0)
    code = _report_run(run, "reach", tmp_path, 900.0, "lockstep", 1)
    text = capsys.readouterr().err
    assert code == 1
    assert "error: the planner failed: ValueError: boom" in text
    assert f"error: the planner exited with code 4; the last lines of {tmp_path}" in text
    assert "  ValueError: boom" in text and "  INFO planning" in text
