"""``m3p2i bench``: bench files, case selection, the results file, statistics; end to end, that a
rerun skips finished trials and that a trial past its time-out is recorded as a failure."""

from __future__ import annotations

import csv
import multiprocessing
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

import shared.config
from m3p2i.bench import (
    FIELDS,
    BenchOptions,
    ResultsFile,
    _TrialQueue,
    load_bench,
    pair_key,
    plan_trials,
    select_cases,
    trial_key,
)
from m3p2i.bench_report import (
    load_paper,
    markdown_table,
    read_results,
    results_report,
    seed_ranges,
    summarize,
    table_rows,
    update_reports,
    wilson,
)
from m3p2i.cli import app
from m3p2i.provenance import machine, versions
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR

ROOT = Path(__file__).resolve().parents[2]


def write_bench(tmp_path, cases, **top):
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump({**top, "cases": cases}))
    return path


def unreachable_scenario(tmp_path, name: str, max_time: float) -> str:
    """navigation with a success test that never holds (exactly on the goal): it ends in
    time-out after ``max_time`` simulated seconds."""
    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    raw["name"] = name
    raw["episode"] = {
        "max_time": max_time,
        "success": [{"near": {"a": "robot", "b": "goal", "within": 0.0, "axes": "xy"}}],
    }
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
    path = write_bench(
        tmp_path,
        [
            {"case": "a", "scenario": "navigation", "trials": 1},
            {"case": "a", "scenario": "navigation", "trials": 1},
        ],
    )
    with pytest.raises(ConfigError, match="duplicate case"):
        load_bench(path)


def test_missing_scenarios_are_skipped_with_the_reason(tmp_path):
    path = write_bench(
        tmp_path,
        [
            {"case": "nav", "scenario": "navigation", "trials": 3},
            {"case": "later", "scenario": "not_written_yet", "trials": 3},
        ],
    )
    ready, skipped = select_cases(load_bench(path))
    assert [r.case.case for r in ready] == ["nav"]
    assert skipped[0].case.case == "later" and "not_written_yet" in skipped[0].reason
    with pytest.raises(ConfigError, match="no case matches"):
        select_cases(load_bench(path), ["push*"])


def test_plan_is_seed_major_and_skips_finished_trials(tmp_path):
    cases = [
        {"case": "a", "scenario": "navigation", "trials": 3},
        {"case": "b", "scenario": "battery_enough", "trials": 1},
    ]
    cfg = load_bench(write_bench(tmp_path, cases, quick_trials=2))
    ready, _ = select_cases(cfg)
    opts = BenchOptions(out_dir=tmp_path, workers=1, timeout=1.0, seed=10)
    planned, todo = plan_trials(ready, cfg, opts, set())
    assert [(t.case.case, t.seed) for t in planned] == [("a", 10), ("b", 10), ("a", 11), ("a", 12)]
    done = {trial_key("a", 11, ready[0].scenario.hash), trial_key("b", 10, "an old hash")}
    _, todo = plan_trials(ready, cfg, opts, done)
    assert [(t.case.case, t.seed) for t in todo] == [("a", 10), ("b", 10), ("a", 12)]
    quick = BenchOptions(out_dir=tmp_path, workers=1, timeout=1.0, quick=True)
    assert len(plan_trials(ready, cfg, quick, set())[0]) == 3  # min(2, 3) + min(2, 1)


def test_workers_without_a_pair_start_on_cases_nobody_serves(tmp_path):
    """Two workers, cases of two trials each: each worker takes a case of its own and its warm
    pair serves it to the end (two pair starts for two cases, where taking the next trial in
    turn started one per trial)."""
    cases = [
        {"case": "a", "scenario": "navigation", "trials": 2},
        {"case": "b", "scenario": "battery_enough", "trials": 2},
    ]
    cfg = load_bench(write_bench(tmp_path, cases))
    ready, _ = select_cases(cfg)
    _, todo = plan_trials(ready, cfg, BenchOptions(out_dir=tmp_path, workers=2, timeout=1.0), set())
    queue = _TrialQueue(todo)
    first, second = queue.take(0, None), queue.take(1, None)  # both start
    assert [(t.case.case, t.seed) for t in (first, second)] == [("a", 0), ("b", 0)]
    # each goes on with its own case, whichever asks first; the last takes what is left
    assert (
        queue.take(1, pair_key(second)).case.case,
        queue.take(0, pair_key(first)).case.case,
    ) == ("b", "a")
    assert queue.take(0, pair_key(first)) is None


def test_results_file_drops_a_torn_last_row(tmp_path):
    path = tmp_path / "results.csv"
    results = ResultsFile(path)
    results.append({"case": "a", "seed": 0, "success": True, "position_error": 0.5})
    with path.open("a") as f:
        f.write("a,,nav,abc,1,1,succ")  # a bench killed mid-write
    results = ResultsFile(path)
    results.append({"case": "a", "seed": 2, "success": False, "reason": "timeout"})
    rows = results.rows()
    assert [(r["case"], r["seed"], r["success"], r["reason"]) for r in rows] == [
        ("a", "0", "1", ""),
        ("a", "2", "0", "timeout"),
    ]
    assert list(rows[0]) == list(FIELDS)


def test_summary_statistics_follow_the_paper():
    """Population std (the paper's 0.0500 (0.2179) for 3 collisions in 60 trials); time over the
    successful trials; killed trials count as failures only."""

    def row(success, collisions, time, reason=""):
        return {
            "case": "push",
            "variant": "push",
            "success": "1" if success else "0",
            "reason": reason,
            "position_error": "0.1",
            "orientation_error": "",
            "collisions": str(collisions),
            "time": str(time),
            "planner_hz": "50",
        }

    rows = (
        [row(True, 1, 5.0)] * 3
        + [row(True, 0, 7.0)] * 56
        + [row(False, 0, 30.0)]
        + [row(False, 9, 3.0, reason="timeout")]
    )
    rows = [{**r, "seed": str(i)} for i, r in enumerate(rows)]
    (s,) = summarize(rows, ["push"])
    assert (s.trials, s.successes, s.killed) == (61, 59, 1)
    assert str(s.stats["collisions"]) == "0.0500 (0.2179)"
    assert s.stats["time"].n == 59 and s.stats["orientation_error"] is None
    cells = table_rows([s], load_paper())[0]
    assert cells[3] == "59/61 (88.8-99.1 %), 1 killed" and cells[9] == "0.0500 (0.2179)"
    assert "| push | push | 0-60 | 59/61" in markdown_table([cells])


def test_wilson_interval_matches_the_textbook_and_stays_in_0_1():
    lo, hi = wilson(49, 50)
    assert (round(lo, 4), round(hi, 4)) == (0.8950, 0.9965)  # e.g. Brown, Cai, DasGupta (2001)
    assert wilson(50, 50)[1] == 1.0 and wilson(0, 2)[0] == 0.0
    assert round(wilson(50, 50)[0], 4) == 0.9286
    with pytest.raises(ValueError):
        wilson(0, 0)


def test_seed_ranges_are_runs_of_consecutive_seeds():
    assert seed_ranges([3, 0, 1, 2, 1000, 1001, 7]) == "0-3, 7, 1000-1001"


def _results(folder, rows, notes=None):
    folder.mkdir(parents=True, exist_ok=True)
    results = ResultsFile(folder / "results.csv")
    for r in rows:
        results.append(
            {
                "variant": "normal",
                "scenario": "pick_place",
                "status": "success",
                "time": 3.0,
                "planner_hz": 15.0,
                "position_error": 0.005,
                "machine": "CPU X, 2 cores",
                "date": "2026-11-30",
                **r,
            }
        )
    if notes:
        (folder / "failures.yaml").write_text(yaml.safe_dump(notes))
    return folder


def test_the_report_names_the_library_versions_where_rows_record_them(tmp_path):
    old = _results(tmp_path / "old", [{"case": "a", "seed": 0, "success": True}])
    new = _results(
        tmp_path / "new",
        [{"case": "b", "seed": 0, "success": True, "versions": "mujoco 4.0.1, torch 2.13.0"}],
    )
    text = results_report([read_results(old), read_results(new)], load_paper())
    assert "Trials ran on CPU X, 2 cores; CPU X, 2 cores (mujoco 4.0.1, torch 2.13.0)," in text


def test_report_counts_the_newest_scenario_version_and_explains_failures(tmp_path):
    rows = [
        {"case": "pick_place", "seed": s, "scenario_hash": "old", "success": False}
        for s in range(3)
    ]  # an earlier version: ignored
    rows += [
        {"case": "pick_place", "seed": s, "scenario_hash": "new", "success": s != 2}
        for s in range(4)
    ]
    rows[-2] = {**rows[-2], "status": "timeout", "time": 30.0, "position_error": 0.377}
    rows.append({"case": "pick_place", "seed": 0, "scenario_hash": "new", "success": True})
    folder = _results(tmp_path / "a", rows, {"pick_place": {2: "Joint 7 at its limit."}})
    res = read_results(folder)
    assert sorted(int(r["seed"]) for r in res.rows) == [0, 1, 2, 3]
    text = results_report([res], load_paper())
    assert "| pick_place | normal | 0-3 | 3/4 (30.1-95.4 %) |" in text
    assert (
        "- `pick_place` seed 2: timeout at 30.0 s, 0.377 m from the goal. Joint 7 at its limit."
        in text
    )
    assert "CPU X, 2 cores, 2026-11-30" in text


def test_failures_without_their_own_note_share_one_line_per_case(tmp_path):
    rows = [
        {
            "case": "trap",
            "seed": s,
            "scenario_hash": "h",
            "success": False,
            "status": "timeout",
            "time": 30.0,
            "position_error": 2.0 + s / 10,
        }
        for s in (0, 1, 2, 5)
    ]
    rows += [{"case": "nav", "seed": 0, "scenario_hash": "h", "success": False}]
    notes = {"trap": {2: "Stuck on the left arm.", "default": "Stalls at the U's back."}}
    text = results_report([read_results(_results(tmp_path / "a", rows, notes))], load_paper())
    assert (
        "- `trap` seed 2: timeout at 30.0 s, 2.200 m from the goal. Stuck on the left arm." in text
    )
    assert (
        "- `trap` seeds 0-1, 5 (3 failures): timeout at 30.0 s, 2.000-2.500 m from the goal. "
        "Stalls at the U's back." in text
    )
    assert "- `nav` seed 0: success at 3.0 s, 0.005 m from the goal. not explained yet" in text


def test_report_blocks_are_regenerated_and_checked(tmp_path):
    _results(
        tmp_path / "r", [{"case": "pick_place", "seed": 0, "scenario_hash": "h", "success": False}]
    )
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# Results\n\n<!-- m3p2i report r -->\nhand-edited\n<!-- end of report -->\nafter\n"
    )
    runner = CliRunner()
    checked = runner.invoke(app, ["report", "--update", str(doc), "--check"])
    assert checked.exit_code == 1 and "out of date" in checked.output
    assert "hand-edited" in doc.read_text()
    assert runner.invoke(app, ["report", "--update", str(doc)]).exit_code == 0
    text = doc.read_text()
    assert "hand-edited" not in text and text.endswith("<!-- end of report -->\nafter\n")
    assert "seed 0: success at 3.0 s" in text and "not explained yet" in text
    assert runner.invoke(app, ["report", "--update", str(doc), "--check"]).exit_code == 0
    missing = tmp_path / "bad.md"
    missing.write_text("<!-- m3p2i report nowhere -->\n<!-- end of report -->\n")
    bad = runner.invoke(app, ["report", "--update", str(missing)])
    assert bad.exit_code == 2 and "no results file" in bad.output
    # a markdown file where results were expected (``--check README.md``): named, not a KeyError
    wrong = runner.invoke(app, ["report", str(doc)])
    assert wrong.exit_code == 2 and "no case, seed, scenario_hash column" in wrong.output


def test_a_grid_block_counts_successes_per_scenario_and_variant(tmp_path):
    rows = [
        {
            "case": "nav_lab",
            "variant": "lab",
            "scenario": "navigation",
            "seed": s,
            "scenario_hash": "h",
            "success": s != 1,
        }
        for s in range(3)
    ]
    rows += [
        {
            "case": "pp_comp",
            "variant": "lab compensated",
            "scenario": "pick_place",
            "seed": s,
            "scenario_hash": "h",
            "success": s == 0,
        }
        for s in range(2)
    ]
    _results(tmp_path / "r", rows)
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- m3p2i grid r -->\nold\n<!-- end of grid -->\n")
    text = update_reports(doc.read_text(), tmp_path, load_paper())
    assert "| scenario | lab | lab compensated |" in text
    assert "| `navigation` | 2/3 | — |" in text and "| `pick_place` | — | 1/2 |" in text
    assert "old" not in text


def test_results_files_written_before_the_machine_column_are_upgraded(tmp_path):
    old = [c for c in FIELDS if c not in ("machine", "date")]
    path = tmp_path / "results.csv"
    path.write_text(
        ",".join(old) + "\n" + ",".join("x" if c == "case" else "0" for c in old) + "\n"
    )
    results = ResultsFile(path)
    results.append({"case": "y", "seed": 1, "machine": "M", "date": "D"})
    rows = results.rows()
    assert [(r["case"], r["machine"]) for r in rows] == [("x", ""), ("y", "M")]


def test_readme_and_docs_tables_are_what_their_results_give():
    """Tables are generated from committed results files, never edited by hand:
    `m3p2i report --update README.md docs/*.md` regenerates them."""
    paper = load_paper()
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text()
        assert update_reports(text, doc.parent, paper) == text, (
            f"{doc.name}: run `m3p2i report --update {doc.relative_to(ROOT)}`"
        )


@pytest.mark.slow
def test_bench_resumes_and_records_a_hung_trial(tmp_path):
    tiny = unreachable_scenario(tmp_path, "tiny", 0.5)
    slow = unreachable_scenario(tmp_path, "endless", 600.0)  # 12000 steps: minutes
    bench = write_bench(
        tmp_path,
        [
            {"case": "tiny", "scenario": tiny, "trials": 2},
            {"case": "endless", "scenario": slow, "trials": 1},
            {"case": "later", "scenario": "not_written_yet", "trials": 1},
        ],
    )
    out = tmp_path / "out"
    runner = CliRunner()

    first = runner.invoke(app, ["bench", str(bench), "--out", str(out), "--cases", "tiny"])
    assert first.exit_code == 0, first.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert sorted(r["seed"] for r in rows) == ["0", "1"]
    assert all(r["status"] == "timeout" and r["reason"] == "" and r["time"] for r in rows)
    assert all((out / r["log"]).is_file() for r in rows)
    # where the digits came from: the machine and the libraries that computed them
    assert all(r["machine"] == machine() and r["versions"] == versions() for r in rows)
    assert versions().startswith("mujoco 4.0.") and ", torch " in versions()
    assert "tiny" in (out / "summary.md").read_text()

    # the endless trial is cut at 5 s (wall clock) and recorded; tiny is not run again
    second = runner.invoke(app, ["bench", str(bench), "--out", str(out), "--timeout", "5"])
    assert second.exit_code == 0, second.output
    assert "2 already" in second.output and "later" in second.output  # skipped, with reason

    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 3  # tiny not rerun; endless once
    hung = [r for r in rows if r["case"] == "endless"]
    assert len(hung) == 1
    (hung,) = hung
    assert hung["reason"] == "timeout" and hung["success"] == "0", hung
    assert 5 <= float(hung["trial_wall"]) < 20

    # one case asked for again: its table printed, the folder's summary keeps every case
    third = runner.invoke(app, ["bench", str(bench), "--out", str(out), "--cases", "tiny"])
    assert third.exit_code == 0, third.output
    summary = (out / "summary.md").read_text()
    assert "| tiny |" in summary and "| endless |" in summary


def test_bench_modes_are_checked_and_recorded(tmp_path):
    path = write_bench(
        tmp_path,
        [{"case": "a", "scenario": "navigation", "trials": 1, "mode": "realtime", "plan_every": 3}],
    )
    with pytest.raises(ConfigError, match="only a lock-step world") as err:
        load_bench(path)
    assert err.value.path == "cases[0].plan_every"
    path = write_bench(
        tmp_path, [{"case": "a", "scenario": "navigation", "trials": 1, "mode": "fast"}]
    )
    with pytest.raises(ConfigError, match="must be one of: lockstep, realtime"):
        load_bench(path)
    cases = load_bench("realtime").cases
    assert {c.mode_label for c in cases} == {
        "realtime",
        "lockstep, plan every 3",
        "realtime, planner at most 25 Hz",
        "realtime, planner at most 15 Hz, world at 0.5x wall clock",
    }


def test_bench_faults_and_compensation_are_checked_and_reach_the_processes(tmp_path, monkeypatch):
    (tmp_path / "slow.yaml").write_text("actuation_delay_ms: 40\n")
    path = write_bench(
        tmp_path,
        [
            {
                "case": "a",
                "scenario": "navigation",
                "trials": 1,
                "faults": "lab",
                "compensate": True,
            },
            {"case": "b", "scenario": "navigation", "trials": 1, "faults": "slow.yaml"},
        ],
    )
    a, b = load_bench(path).cases
    assert a.delays == (25.0, 25.0) and a.mode_label == "lockstep, faults lab, compensated"
    assert b.faults == str(tmp_path / "slow.yaml") and b.delays is None
    for case, key, message in [
        ({"faults": "office"}, "faults", "neither a profile nor a file"),
        ({"compensate": True}, "compensate", "no delay to compensate"),
        ({"faults": "lab", "compensate": "yes"}, "compensate", "wrong type"),
        ({"compensate": "measure"}, "compensate", "no delay to compensate"),
    ]:
        path = write_bench(tmp_path, [{"case": "c", "scenario": "navigation", "trials": 1, **case}])
        with pytest.raises(ConfigError, match=message) as err:
            load_bench(path)
        assert err.value.path == f"cases[0].{key}"
    path = write_bench(
        tmp_path, [{"case": "d", "scenario": "navigation", "trials": 1, "max_rate": 5}]
    )
    with pytest.raises(ConfigError, match="only a real-time world") as err:
        load_bench(path)
    assert err.value.path == "cases[0].max_rate"
    for factor, message in [(0.5, "only a real-time world has a wall clock"), (0, "> 0")]:
        path = write_bench(
            tmp_path,
            [{"case": "e", "scenario": "navigation", "trials": 1, "realtime_factor": factor}],
        )
        with pytest.raises(ConfigError, match=message) as err:
            load_bench(path)
        assert err.value.path == "cases[0].realtime_factor"
    from m3p2i.launch import EpisodeLaunch

    launch = EpisodeLaunch(
        scenario="navigation.yaml", run_dir=tmp_path, mode="realtime", realtime_factor=0.5
    )
    server = launch.commands(5555)["server"]
    assert server[server.index("--realtime-factor") + 1] == "0.5"
    assert (
        "--realtime-factor"
        not in EpisodeLaunch(scenario="n.yaml", run_dir=tmp_path).commands(5555)["server"]
    )
    path = write_bench(
        tmp_path,
        [
            {
                "case": "f",
                "scenario": "navigation",
                "trials": 1,
                "faults": "lab",
                "compensate": "measure",
            }
        ],
    )
    (f,) = load_bench(path).cases
    old = path.read_text().replace("compensate: measure", "compensate: estimate")
    path.write_text(old)  # the old spelling: the same case, and a warning naming the new one
    monkeypatch.setattr(shared.config, "_WARNED", set())  # each old spelling is warned of once
    with pytest.warns(FutureWarning, match="write compensate: measure"):
        assert load_bench(path).cases == (f,)
    assert f.measure_delays and f.delays is None and f.mode_label.endswith("delays estimated")
    assert (
        "--measure-delays"
        in EpisodeLaunch(scenario="n.yaml", run_dir=tmp_path, measure_delays=True).commands(5555)[
            "planner"
        ]
    )
    robustness = load_bench("robustness").cases
    assert {c.faults for c in robustness} == {"", "lab", "harsh"}
    assert all(c.delays is not None for c in robustness if c.case.endswith("_comp"))


def test_realtime_trials_run_last_and_alone_on_every_core(tmp_path, monkeypatch):
    import threading
    import time as _time

    from m3p2i import bench as B

    log, running, lock = [], [], threading.Lock()

    def fake_trial(trial, opts, threads, stop, slot=None):
        with lock:
            running.append(trial.case.mode)
            log.append((trial.case.mode, threads, list(running)))
        _time.sleep(0.05)
        with lock:
            running.remove(trial.case.mode)
        return {"case": trial.case.case, "seed": trial.seed}

    monkeypatch.setattr(B, "run_trial", fake_trial)
    monkeypatch.setattr(B.os, "cpu_count", lambda: 4)
    cases = [
        B.BenchCase("w", "", "navigation", 3),
        B.BenchCase("r", "", "navigation", 3, "realtime"),
    ]
    todo = [B.Trial(c, None, None, seed) for seed in range(3) for c in cases]
    opts = BenchOptions(out_dir=tmp_path, workers=2, timeout=10)
    assert B.run_trials(todo, opts, ResultsFile(tmp_path / "results.csv"))
    modes = [m for m, _, _ in log]
    assert modes == ["lockstep"] * 3 + ["realtime"] * 3  # the waiting world first
    assert all(t == 4 and now == ["realtime"] for m, t, now in log if m == "realtime")
    assert all(t == 2 for m, t, _ in log if m == "lockstep")


def test_loaded_trials_run_last_alone_under_their_busy_processes(tmp_path, monkeypatch):
    from m3p2i import bench as B

    seen = []

    def fake_trial(trial, opts, threads, stop, slot=None):
        busy = len([p for p in multiprocessing.active_children() if p.name.startswith("busy-")])
        seen.append((trial.case.case, busy))
        return {"case": trial.case.case, "seed": trial.seed}

    monkeypatch.setattr(B, "run_trial", fake_trial)
    cases = [
        B.BenchCase("loaded", "", "navigation", 2, "realtime", load=2),
        B.BenchCase("idle", "", "navigation", 2, "realtime"),
    ]
    todo = [B.Trial(c, None, None, seed) for seed in range(2) for c in cases]
    opts = BenchOptions(out_dir=tmp_path, workers=2, timeout=10)
    assert B.run_trials(todo, opts, ResultsFile(tmp_path / "results.csv"))
    assert seen == [("idle", 0), ("idle", 0), ("loaded", 2), ("loaded", 2)]
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("busy-")]
    assert cases[0].mode_label == "realtime, 2 busy processes"
    path = write_bench(tmp_path, [{"case": "a", "scenario": "navigation", "trials": 1, "load": -1}])
    with pytest.raises(ConfigError, match="busy processes") as err:
        load_bench(path)
    assert err.value.path == "cases[0].load"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--mode", "bogus"], "--mode bogus: unknown mode (expected lockstep or realtime)"),
        (["--realtime-factor", "0.5"], "--realtime-factor 0.5: only a real-time world"),
        (["--planner-max-rate", "20"], "--planner-max-rate 20.0: only a real-time world"),
        (["--mode", "realtime", "--plan-every", "3"], "--plan-every 3: only a lock-step world"),
    ],
)
def test_run_refuses_options_its_mode_would_ignore(args, message):
    """What the bench refuses by key, ``m3p2i run`` refuses by flag (one check,
    server.options.mode_conflicts), before anything starts."""
    from typer.testing import CliRunner

    from m3p2i.cli import app

    result = CliRunner().invoke(app, ["run", "navigation", *args])
    assert result.exit_code == 2 and message in result.output, result.output


def _children(pid: int) -> set[int]:
    """The live child processes of ``pid`` (Linux /proc)."""
    out = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:  # a thread may end between the listing and the read
            out |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            continue
    return out


def _alive(pid: int) -> bool:
    status = Path(f"/proc/{pid}/status")
    try:  # a zombie has exited: only its parent has yet to read its code
        return "\nState:\tZ" not in status.read_text()
    except FileNotFoundError:
        return False


def test_sigterm_stops_the_episode_processes_as_ctrl_c_does(tmp_path):
    """``kill`` (a scheduler, a CI time-out) on a bench must not leave a world and a planner
    running: SIGTERM takes Ctrl-C's path, which stops them and keeps the finished rows."""
    import signal
    import subprocess
    import sys
    import time

    bench = write_bench(
        tmp_path,
        [{"case": "e", "scenario": unreachable_scenario(tmp_path, "endless", 600.0), "trials": 1}],
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "m3p2i", "bench", str(bench), "--out", str(tmp_path / "o")],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline, kids = time.monotonic() + 120, set()
        while time.monotonic() < deadline and proc.poll() is None:
            kids = _children(proc.pid)
            if len(kids) >= 2:  # world and planner started
                break
            time.sleep(0.2)
        assert len(kids) >= 2, "the episode's processes never started"
        time.sleep(3.0)  # into the episode
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(k) for k in kids):
            time.sleep(0.2)
        assert not any(_alive(k) for k in kids), "episode processes outlived SIGTERM"
    finally:
        if proc.poll() is None:
            proc.kill()
