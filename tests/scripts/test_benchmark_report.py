"""scripts/benchmark.py's report (scripts.measure.speed_report): the speed table in docs/speed.md
is generated from a results file (median and range over the runs), never typed; regenerating it
changes nothing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import typer

from scripts.measure import speed_report
from tests.helpers import ENV

ROOT = Path(__file__).resolve().parents[2]


def _row(run: int, hz: float, ratio: float) -> dict:
    return {
        "scenario": "navigation",
        "samples": 200,
        "horizon": 5,
        "planning_step": 0.15,
        "hz": hz,
        "iteration_ms": 1000 / hz,
        "ratio_to_rollout": ratio / 3,
        "ratio_to_own_rollout": ratio,
        "ratio_to_sensor_rollout": ratio - 0.1,
        "rollout_ms": 3000 / hz / ratio,
        "own_rollout_ms": 1000 / hz / ratio,
        "sensor_rollout_ms": 1000 / hz / (ratio - 0.1),
        "run": run,
    }


def test_the_speed_table_gives_median_and_range_over_the_runs(tmp_path):
    results = {
        "command": "python scripts/benchmark.py --runs 3 --out x.json",
        "date": "2026-11-30",
        "machine": "a CPU, 2 cores",
        "threads": 2,
        "iterations": 200,
        "runs": 3,
        "rows": [_row(0, 300.0, 1.5), _row(1, 200.0, 1.3), _row(2, 250.0, 1.4)],
    }
    (tmp_path / "speed.json").write_text(json.dumps(results))
    doc = "intro\n<!-- benchmark speed.json -->\nstale\n<!-- end of benchmark -->\nafter\n"
    new = speed_report.update(doc, tmp_path)
    row = next(line for line in new.splitlines() if line.startswith("| `navigation`"))
    assert "200 × 5 × 0.15 s" in row and "250.0 (200.0-300.0)" in row and "1.40 (1.30-1.50)" in row
    assert "stale" not in new and new.startswith("intro\n") and new.endswith("after\n")
    assert "over 3 runs of `python scripts/benchmark.py --runs 3 --out x.json`" in new
    assert speed_report.update(new, tmp_path) == new
    with pytest.raises(typer.BadParameter, match="no '<!-- benchmark PATH -->'"):
        speed_report.update("no block here", tmp_path)


def test_a_seen_scenario_is_set_against_its_declared_obstacles_run_by_run():
    def case(name: str, run: int, ms: float, **extra) -> dict:
        return {**_row(run, 1000 / ms, 1.5), "scenario": name, **extra}

    mapped = {"map_rate_hz": 10.0}
    results = {
        "command": "c",
        "date": "d",
        "machine": "m",
        "threads": 2,
        "iterations": 200,
        "runs": 2,
        "rows": [
            case("navigation_clear", 0, 2.0),
            case("navigation_seen", 0, 2.2, map_update_ms=3.0, map_core_share=0.03, **mapped),
            case("navigation_clear", 1, 4.0),  # a slow run: the ratio pairs runs, not medians
            case("navigation_seen", 1, 4.0, map_update_ms=5.0, map_core_share=0.05, **mapped),
        ],
    }
    text = speed_report.markdown(results, "x.json")
    row = next(line for line in text.splitlines() if line.startswith("| `navigation_seen` | 3.10"))
    assert "1.05 (1.00-1.10) × `navigation_clear`" in row
    assert "| 4.00 (3.00-5.00) | 10 | 0.040 (0.030-0.050) |" in row
    plain = {**results, "rows": [case("navigation", 0, 2.0)]}
    assert "map update" not in speed_report.markdown(plain, "x.json")


def test_the_phase_split_is_the_median_of_each_phase_and_its_share():
    rows = [
        {**_row(0, 200.0, 1.3), "phases_ms": {"mirror": 0.1, "rollout": 3.0, "costs": 0.9}},
        {**_row(1, 200.0, 1.3), "phases_ms": {"mirror": 0.3, "rollout": 4.0, "costs": 1.1}},
        {**_row(2, 200.0, 1.3), "phases_ms": {"mirror": 0.2, "rollout": 5.0, "costs": 1.0}},
    ]
    results = {"command": "c", "date": "d", "machine": "m", "threads": 2, "iterations": 9}
    text = speed_report.markdown({**results, "runs": 3, "rows": rows}, "x.json")
    assert "| scenario | mirror | rollout | costs |" in text
    assert "| `navigation` | 0.200 (4 %) | 4.000 (77 %) | 1.000 (19 %) |" in text


def test_the_rest_of_an_iteration_is_set_beside_its_rest_with_the_rollout_replayed():
    def row(run: int, rest: float, replayed: float) -> dict:
        split = {"mirror": rest / 2, "rollout": 3.0 + run, "costs": rest / 2}
        floor = {"mirror": replayed / 2, "rollout": 0.01, "costs": replayed / 2}
        return {**_row(run, 200.0, 1.3), "phases_ms": split, "phases_replayed_ms": floor}

    results = {"command": "c", "date": "d", "machine": "m", "threads": 2, "iterations": 9}
    rows = [row(0, 1.0, 0.5), row(1, 1.2, 0.7), row(2, 1.4, 0.6)]
    text = speed_report.markdown({**results, "runs": 3, "rows": rows}, "x.json")
    assert "| `navigation` | 1.20 (1.00-1.40) | 0.60 (0.50-0.70) | 4.00 (3.00-5.00) |" in text
    # a results file from before the replayed split has no such table
    old = [{k: v for k, v in r.items() if k != "phases_replayed_ms"} for r in rows]
    assert "replayed" not in speed_report.markdown({**results, "runs": 3, "rows": old}, "x.json")


def _results(hz: float) -> dict:
    return {
        **{"command": "c", "date": "d", "machine": "m", "threads": 2, "iterations": 200},
        **{"runs": 1, "rows": [_row(0, hz, 1.3)]},
    }


def test_report_regenerates_only_the_blocks_that_name_it(tmp_path):
    for name, hz in (("a.json", 100.0), ("b.json", 400.0)):
        (tmp_path / name).write_text(json.dumps(_results(hz)))
    doc = tmp_path / "doc.md"
    doc.write_text(
        "<!-- benchmark a.json -->\nold a\n<!-- end of benchmark -->\n"
        "<!-- benchmark b.json -->\nold b\n<!-- end of benchmark -->\n"
    )
    new = speed_report.update(doc.read_text(), tmp_path, only=tmp_path / "b.json")
    assert "old a" in new and "old b" not in new and "400.0" in new
    with pytest.raises(typer.BadParameter, match=r"no block names .*c\.json.*a\.json, b\.json"):
        speed_report.update(doc.read_text(), tmp_path, only=tmp_path / "c.json")
    (tmp_path / "a.json").unlink()
    with pytest.raises(typer.BadParameter, match=r"<!-- benchmark a\.json -->: no file .*a\.json"):
        speed_report.update(doc.read_text(), tmp_path)
    (tmp_path / "b.json").write_text("{not json")
    with pytest.raises(typer.BadParameter, match=r"b\.json is not a JSON results file"):
        speed_report.update(doc.read_text(), tmp_path, only=tmp_path / "b.json")


def test_the_command_updates_from_report_and_prints_a_report_alone(tmp_path):
    def benchmark(*args: str) -> subprocess.CompletedProcess:
        script = ROOT / "scripts" / "benchmark.py"
        env = {**ENV, "COLUMNS": "200"}
        return subprocess.run(
            [sys.executable, str(script), *args], capture_output=True, text=True, env=env
        )

    (tmp_path / "r.json").write_text(json.dumps(_results(250.0)))
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- benchmark r.json -->\nold\n<!-- end of benchmark -->\n")
    report = ["--report", str(tmp_path / "r.json")]
    run = benchmark(*report, "--update", str(doc))
    assert run.returncode == 0, run.stderr
    assert "250.0" in doc.read_text() and "old" not in doc.read_text()
    shown = benchmark(*report)
    assert shown.returncode == 0, shown.stderr
    assert "navigation" in shown.stdout and "250.0" in shown.stdout
    assert "rollout replayed" not in shown.stdout  # a file from before the replayed split
    split = {"mirror": 0.25, "rollout": 3.0, "costs": 0.5}
    replayed = {**_row(0, 250.0, 1.3), "phases_ms": split, "phases_replayed_ms": split}
    (tmp_path / "r.json").write_text(json.dumps({**_results(250.0), "rows": [replayed]}))
    shown = benchmark(*report)
    assert "rollout replayed" in shown.stdout and "0.750" in shown.stdout
    missing = benchmark("--report", str(tmp_path / "none.json"))
    assert missing.returncode == 2 and "no file" in missing.stderr
    (tmp_path / "other.json").write_text('{"a": 1}')
    other = benchmark("--report", str(tmp_path / "other.json"))
    assert other.returncode == 2 and "no 'rows' (expected a file written by --out)" in other.stderr
