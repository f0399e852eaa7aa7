"""Parameter sweeps of ``m3p2i bench``: ``--set`` and ``sweep:`` parsing, variants read by the
scenario loader (a bad key or value stops the bench before any trial), each variant's own hash
and overrides in results.csv, and the per-key tables and plots."""

from __future__ import annotations

import csv

import pytest
import yaml
from typer.testing import CliRunner

from m3p2i.bench import BenchOptions, ResultsFile, load_bench, plan_trials, select_cases
from m3p2i.bench_report import read_results, results_report
from m3p2i.cli import app
from m3p2i.sweep import (
    Sweep,
    apply_overrides,
    parse_set,
    plot_sweep,
    split_values,
    sweep_points,
    sweep_report,
    swept_keys,
)
from shared.config import ConfigError
from shared.scenario import load_scenario


def write_bench(tmp_path, cases, **top):
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump({**top, "cases": cases}))
    return path


def test_set_values_are_yaml_and_commas_inside_brackets_stay():
    assert split_values("25, 50,[1, 2],{a: 1, b: 2},'x,y'") == [
        "25",
        "50",
        "[1, 2]",
        "{a: 1, b: 2}",
        "'x,y'",
    ]
    sweep = parse_set(["planner.samples=50,100,50", "planner.mppi.alpha_u=0.5,1", "x.flag=true"])
    assert sweep.keys == (
        ("planner.samples", (50, 100)),
        ("planner.mppi.alpha_u", (0.5, 1)),
        ("x.flag", (True,)),
    )
    assert len(sweep.variants()) == 4
    assert sweep.variants()[1] == {"planner.samples": 50, "planner.mppi.alpha_u": 1, "x.flag": True}
    assert Sweep().variants() == [{}]
    for bad in ("planner.samples", "=1,2", "planner.samples="):
        with pytest.raises(ConfigError, match="not KEY=VALUE"):
            parse_set([bad])
    merged = Sweep((("a", (1,)), ("b", (2,)))).merged(parse_set(["b=3,4"]))
    assert merged.keys == (("a", (1,)), ("b", (3, 4)))


def test_overrides_copy_the_mapping_and_create_missing_sections():
    raw = {"planner": {"samples": 200, "mppi": {"alpha_u": 1.0}}, "name": "n"}
    out = apply_overrides(raw, {"planner.samples": 50, "planner.mppi.noise": [0.1, 0.2]})
    assert out["planner"] == {"samples": 50, "mppi": {"alpha_u": 1.0, "noise": [0.1, 0.2]}}
    assert raw["planner"]["samples"] == 200 and "noise" not in raw["planner"]["mppi"]
    with pytest.raises(ConfigError, match="name is not a mapping"):
        apply_overrides(raw, {"name.x": 1})


def test_sweep_variants_have_their_own_hash_file_and_overrides(tmp_path):
    cfg = load_bench(
        write_bench(
            tmp_path,
            [{"case": "nav", "scenario": "navigation", "trials": 2}],
            sweep={"planner.samples": [50, 100]},
        )
    )
    assert cfg.sweep.keys == (("planner.samples", (50, 100)),)
    ready, _ = select_cases(cfg, variant_dir=tmp_path / "v")
    assert [rc.overrides for rc in ready] == [{"planner.samples": 50}, {"planner.samples": 100}]
    assert len({rc.scenario.hash for rc in ready}) == 2
    assert ready[0].scenario.hash != load_scenario("navigation").hash
    for rc in ready:  # the file both processes load reads back to the same scenario
        again = load_scenario(rc.scenario.source)
        assert again.hash == rc.scenario.hash and again.name == "navigation"
        assert again.planner.samples == rc.overrides["planner.samples"]
    planned, _todo = plan_trials(ready, cfg, BenchOptions(tmp_path, 1, 1.0), set())
    assert [(t.seed, t.overrides["planner.samples"]) for t in planned] == [
        (0, 50),
        (0, 100),
        (1, 50),
        (1, 100),
    ]
    assert planned[0].log_dir.as_posix() == "logs/nav@planner.samples=50/seed-000"
    # --set replaces the file's values of a key; the resume key follows the content
    ready2, _ = select_cases(
        cfg,
        sweep=cfg.sweep.merged(parse_set(["planner.samples=100,200"])),
        variant_dir=tmp_path / "v",
    )
    assert ready2[0].scenario.hash == ready[1].scenario.hash
    with pytest.raises(ConfigError, match="non-empty list"):
        load_bench(
            write_bench(
                tmp_path,
                [{"case": "nav", "scenario": "navigation", "trials": 1}],
                sweep={"planner.samples": 50},
            )
        )


@pytest.mark.parametrize(
    "setting, message",
    [
        ("planner.samplez=50,100", "planner.samplez: unknown key"),
        ("planner.samples=100,0", "planner.samples: must be a positive integer (got 0)"),
    ],
)
def test_a_bad_set_is_the_loaders_error_before_any_trial(tmp_path, setting, message):
    bench = write_bench(tmp_path, [{"case": "nav", "scenario": "navigation", "trials": 1}])
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["bench", str(bench), "--out", str(out), "--set", setting])
    assert result.exit_code == 2, result.output
    assert message in result.output and "navigation.yaml with --set" in result.output
    assert not (out / "results.csv").exists() and not (out / "logs").exists()


def _row(case, samples, seed, success, time="", reason="", hz="50.0", hits=""):
    return {
        "case": case,
        "variant": "v",
        "scenario": case,
        "scenario_hash": f"h{samples}",
        "seed": seed,
        "success": success,
        "status": "success" if success else "timeout",
        "reason": reason,
        "time": time,
        "planner_hz": hz,
        "machine": "CPU X, 2 cores",
        "date": "2026-11-30",
        "overrides": f'{{"planner.samples": {samples}}}',
        "collisions": hits,
    }


def test_sweep_tables_and_plot_per_key(tmp_path):
    results = ResultsFile(tmp_path / "results.csv")
    for r in [
        _row("push", 200, 0, True, 4.0),
        _row("push", 200, 1, True, 6.0),
        _row("push", 25, 0, False, hits="1"),
        _row("push", 25, 1, True, 8.0, hits="0"),
        _row("pull", 25, 0, False, reason="timeout", hz=""),
        _row("pull", 25, 1, False),
    ]:
        results.append(r)
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert swept_keys(rows) == ["planner.samples"]
    points = sweep_points(rows, "planner.samples")
    assert [(p.case, p.value, p.successes, p.trials) for p in points] == [
        ("push", 25, 1, 2),
        ("push", 200, 2, 2),
        ("pull", 25, 0, 2),
    ]
    assert points[1].time == (5.0, 1.0)
    text = sweep_report(rows)
    assert "| push | 25 | 2 | 1/2 (9-91 %) | 8.00 (0.00) | 0.50 | 50.0 |" in text
    assert "| pull | 25 | 2 | 0/2 (0-66 %) | — | — | 50.0 |" in text
    # a report of the file gives the same tables: variants are side by side, not versions
    assert text in results_report([read_results(tmp_path)], {})
    (png,) = plot_sweep(rows, tmp_path / "plots")
    assert png.name == "sweep-planner.samples.png" and png.read_bytes()[:4] == b"\x89PNG"
