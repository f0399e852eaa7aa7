"""``m3p2i bench``: bench files, case selection, the results file, statistics; end to end, that a
rerun skips finished trials and that a trial past its time-out is recorded as a failure."""

from __future__ import annotations

import csv

import pytest
import yaml
from typer.testing import CliRunner

from shared.tools.bench import (FIELDS, BenchOptions, ResultsFile, load_bench, plan_trials,
                          select_cases, trial_key)
from shared.tools.bench_report import load_paper, markdown_table, summarize, table_rows
from shared.tools.cli import app
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR


def write_bench(tmp_path, cases, **top):
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump({**top, "cases": cases}))
    return path


def unreachable_scenario(tmp_path, name: str, max_time: float) -> str:
    """navigation with a success test that never holds (exactly on the goal): it ends in
    time-out after ``max_time`` simulated seconds."""
    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["name"] = name
    raw["episode"] = {"max_time": max_time, "success": [
        {"near": {"a": "robot", "b": "goal", "within": 0.0, "axes": "xy"}}]}
    (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(raw))
    return f"{name}.yaml"


def test_paper_bench_cases_and_published_rows_agree():
    cfg = load_bench("paper")
    names = [c.case for c in cfg.cases]
    paper = load_paper()
    assert set(paper) <= set(names)
    assert paper["push"].cell("collisions") == "0.0500 (0.2179)"
    assert paper["corner2_push"].cell("time") == "time-out"
    assert paper["pick_place"].cell("time") == "—"


def test_bench_file_errors_name_the_key(tmp_path):
    path = write_bench(tmp_path, [{"case": "a", "scenario": "navigation", "trials": 0}])
    with pytest.raises(ConfigError) as err:
        load_bench(path)
    assert err.value.path == "cases[0].trials"
    path = write_bench(tmp_path, [{"case": "a", "scenario": "navigation", "trials": 1},
                                  {"case": "a", "scenario": "navigation", "trials": 1}])
    with pytest.raises(ConfigError, match="duplicate case"):
        load_bench(path)


def test_missing_scenarios_are_skipped_with_the_reason(tmp_path):
    path = write_bench(tmp_path, [{"case": "nav", "scenario": "navigation", "trials": 3},
                                  {"case": "later", "scenario": "not_written_yet", "trials": 3}])
    ready, skipped = select_cases(load_bench(path))
    assert [r.case.case for r in ready] == ["nav"]
    assert skipped[0].case.case == "later" and "not_written_yet" in skipped[0].reason
    with pytest.raises(ConfigError, match="no case matches"):
        select_cases(load_bench(path), ["push*"])


def test_plan_is_seed_major_and_skips_finished_trials(tmp_path):
    cases = [{"case": "a", "scenario": "navigation", "trials": 3},
             {"case": "b", "scenario": "battery_enough", "trials": 1}]
    cfg = load_bench(write_bench(tmp_path, cases, quick_trials=2))
    ready, _ = select_cases(cfg)
    opts = BenchOptions(out_dir=tmp_path, workers=1, timeout=1.0, seed=10)
    planned, todo = plan_trials(ready, cfg, opts, set())
    assert [(t.case.case, t.seed) for t in planned] == [("a", 10), ("b", 10), ("a", 11), ("a", 12)]
    done = {trial_key("a", 11, ready[0].scenario.hash), trial_key("b", 10, "an old hash")}
    _, todo = plan_trials(ready, cfg, opts, done)
    assert [(t.case.case, t.seed) for t in todo] == [("a", 10), ("b", 10), ("a", 12)]
    quick = BenchOptions(out_dir=tmp_path, workers=1, timeout=1.0, quick=True)
    assert len(plan_trials(ready, cfg, quick, set())[0]) == 3          # min(2, 3) + min(2, 1)


def test_results_file_drops_a_torn_last_row(tmp_path):
    path = tmp_path / "results.csv"
    results = ResultsFile(path)
    results.append({"case": "a", "seed": 0, "success": True, "position_error": 0.5})
    with path.open("a") as f:
        f.write("a,,nav,abc,1,1,succ")                     # a bench killed mid-write
    results = ResultsFile(path)
    results.append({"case": "a", "seed": 2, "success": False, "reason": "timeout"})
    rows = results.rows()
    assert [(r["case"], r["seed"], r["success"], r["reason"]) for r in rows] == \
        [("a", "0", "1", ""), ("a", "2", "0", "timeout")]
    assert list(rows[0]) == list(FIELDS)


def test_summary_statistics_follow_the_paper():
    """Population std (the paper's 0.0500 (0.2179) for 3 collisions in 60 trials); time over the
    successful trials; killed trials count as failures only."""
    def row(success, collisions, time, reason=""):
        return {"case": "push", "variant": "push", "success": "1" if success else "0",
                "reason": reason, "position_error": "0.1", "orientation_error": "",
                "collisions": str(collisions), "time": str(time), "planner_hz": "50"}
    rows = [row(True, 1, 5.0)] * 3 + [row(True, 0, 7.0)] * 56 + [row(False, 0, 30.0)] + \
        [row(False, 9, 3.0, reason="timeout")]
    (s,) = summarize(rows, ["push"])
    assert (s.trials, s.successes, s.killed) == (61, 59, 1)
    assert str(s.stats["collisions"]) == "0.0500 (0.2179)"
    assert s.stats["time"].n == 59 and s.stats["orientation_error"] is None
    cells = table_rows([s], load_paper())[0]
    assert cells[3] == "59/61 (1 killed)" and cells[9] == "0.0500 (0.2179)"
    assert "| push | push | 61 |" in markdown_table([cells])


@pytest.mark.slow
def test_bench_resumes_and_records_a_hung_trial(tmp_path):
    tiny = unreachable_scenario(tmp_path, "tiny", 0.5)
    slow = unreachable_scenario(tmp_path, "endless", 600.0)   # 12000 steps: minutes
    bench = write_bench(tmp_path, [{"case": "tiny", "scenario": tiny, "trials": 2},
                                   {"case": "endless", "scenario": slow, "trials": 1},
                                   {"case": "later", "scenario": "not_written_yet", "trials": 1}])
    out = tmp_path / "out"
    runner = CliRunner()

    first = runner.invoke(app, ["bench", str(bench), "--out", str(out), "--cases", "tiny"])
    assert first.exit_code == 0, first.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert sorted(r["seed"] for r in rows) == ["0", "1"]
    assert all(r["status"] == "timeout" and r["reason"] == "" and r["time"] for r in rows)
    assert all((out / r["log"]).is_file() for r in rows)
    assert "tiny" in (out / "summary.md").read_text()

    # the endless trial is cut at 5 s (wall clock) and recorded; tiny is not run again
    second = runner.invoke(app, ["bench", str(bench), "--out", str(out), "--timeout", "5"])
    assert second.exit_code == 0, second.output
    assert "2 already" in second.output and "later" in second.output   # skipped, with reason

    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 3                                 # tiny not rerun; endless once
    hung = [r for r in rows if r["case"] == "endless"]
    assert len(hung) == 1
    (hung,) = hung
    assert hung["reason"] == "timeout" and hung["success"] == "0", hung
    assert 5 <= float(hung["trial_wall"]) < 20

