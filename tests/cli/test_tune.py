"""``m3p2i tune``: the space file read strictly, a bad scenario key refused by the loader before
any trial, a study deterministic for its seed that resumes after an interruption and prunes
hopeless trials (the study logic on a stand-in runner that scores a set from its scenario), the
overlay loadable, and the shipped example end to end (slow: real episodes)."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from m3p2i.cli import app
from m3p2i.tune import (
    Events,
    TuneOptions,
    best_values,
    check_space,
    holdout,
    load_space,
    parse_seeds,
    report,
    resolve_target,
    run_study,
    values_id,
    write_overlay,
)
from shared.config import ConfigError
from shared.scenario import load_scenario

pytest.importorskip("optuna")

WEIGHT = "objectives.navigate.terms[1].weight"
SPACE = {
    "params": {
        "planner.samples": {"low": 20, "high": 80, "log": True},
        WEIGHT: {"low": 0.01, "high": 0.2, "log": True},
        "planner.mppi.eta_bounds": {"choices": [[3.0, 10.0], [2.0, 6.0]]},
    }
}


def write_space(tmp_path, data, name="space.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


class StandIn:
    """A runner that scores a parameter set from its scenario instead of running episodes:
    success needs 40 samples or more on odd seeds; time grows with the contact weight. Records
    what it was asked to run; ``stop_after`` rows, it reports an interruption (Ctrl-C). With a
    ``reason`` (``timeout``) every episode ends as the bench records one killed: no outcome."""

    def __init__(self, stop_after: int | None = None, reason: str = ""):
        self.ran: list[tuple[str, int]] = []
        self.stop_after = stop_after
        self.reason = reason

    def __call__(self, trials, results, on_done):
        for t in trials:
            if self.stop_after is not None and len(self.ran) >= self.stop_after:
                return False
            raw = t.scenario.raw
            samples = raw["planner"]["samples"]
            weight = raw["objectives"]["navigate"]["terms"][1]["weight"]
            won = (samples >= 40 or t.seed % 2 == 0) and not self.reason
            row = {
                "case": t.case.case,
                "scenario": t.scenario.name,
                "scenario_hash": t.scenario.hash,
                "seed": t.seed,
                "success": won,
                "status": "success" if won else "unfinished" if self.reason else "timeout",
                "reason": self.reason,
                "time": 3.0 + 10 * weight if won else 30.0,
                "position_error": 0.05,
                "trial_wall": 1.0,
                "log": str(t.log_dir / "episode.jsonl"),
            }
            results.append(row)
            self.ran.append((t.case.case, t.seed))
            on_done(row)
        return True


def study(tmp_path, out, trials, runner, seeds=(0, 1), space=None, sampler_seed=0):
    target = resolve_target("navigation")
    space = load_space(space or write_space(tmp_path, SPACE))
    opts = TuneOptions(out=out, trials=trials, seeds=seeds, sampler_seed=sampler_seed)
    return target, space, opts, run_study(target, space, opts, runner)


def params(s):
    done = ("COMPLETE", "PRUNED")
    return [t.user_attrs["values"] for t in s.trials if t.state.name in done]


def test_a_study_is_deterministic_for_its_seed_and_resumes(tmp_path):
    _, _, _, a = study(tmp_path, tmp_path / "a", 3, StandIn())
    assert len(params(a)) == 3
    # a second study of the same seed: 2 trials, then 3 in all; only the third runs, and the
    # three are the first study's
    study(tmp_path, tmp_path / "b", 2, StandIn())
    third = StandIn()
    _, _, _, b = study(tmp_path, tmp_path / "b", 3, third)
    assert len({case for case, _ in third.ran}) == 1
    assert params(b) == params(a)


def test_an_interrupted_trial_is_proposed_again_and_keeps_its_finished_seeds(tmp_path):
    _, _, _, a = study(tmp_path, tmp_path / "a", 2, StandIn())
    cut = StandIn(stop_after=3)  # trial 0's two seeds, then trial 1's first: Ctrl-C
    assert study(tmp_path, tmp_path / "b", 2, cut)[3] is None
    rest = StandIn()
    _, _, _, b = study(tmp_path, tmp_path / "b", 2, rest)
    assert [seed for _, seed in rest.ran] == [1]  # seed 0 of trial 1 was kept
    assert params(b) == params(a)
    assert [t.state.name for t in b.trials] == ["COMPLETE", "FAIL", a.trials[1].state.name]


def test_a_trial_that_cannot_beat_the_best_stops_early(tmp_path):
    # the original's 200 samples is outside the space; trial 0 then succeeds on every seed only
    # with 40 samples or more; a set under 40 fails seed 1 and is pruned before seeds 2-3
    space = {"params": {"planner.samples": {"choices": [60, 20]}}, "startup_trials": 5}
    runner = StandIn()
    *_, s = study(
        tmp_path, tmp_path / "s", 4, runner, seeds=(0, 1, 2, 3), space=write_space(tmp_path, space)
    )
    low = [t for t in s.trials if t.user_attrs["values"]["planner.samples"] == 20]
    first_complete = next(t.number for t in s.trials if t.state.name == "COMPLETE")
    assert low and all(t.state.name == "PRUNED" for t in low if t.number > first_complete)
    # the set under 40 ran seeds 2-3 only if it came first (nothing to beat yet); a set seen
    # before reuses its rows instead of running them again
    low_case = f"navigation@{values_id({'planner.samples': 20})}"
    ran = sorted(seed for case, seed in runner.ran if case == low_case)
    assert ran == ([0, 1, 2, 3] if low[0].number == 0 else [0, 1])
    assert best_values(s)[1] == {"planner.samples": 60}


def test_the_overlay_is_a_base_plus_the_tuned_keys_and_loads(tmp_path):
    target, space, opts, s = study(tmp_path, tmp_path / "s", 3, StandIn())
    _, values = best_values(s)
    path = write_overlay(target, space, values, opts.out)
    data = yaml.safe_load(path.read_text())
    assert data["base"] == "navigation"
    assert set(data) == {"base", "name", "description", "planner", "objectives"}
    tuned, original = load_scenario(path), load_scenario("navigation")
    assert tuned.planner.samples == values["planner.samples"]
    assert tuned.objectives["navigate"].terms[1].weight == values[WEIGHT]
    assert list(tuned.planner.mppi.eta_bounds) == values["planner.mppi.eta_bounds"]
    # the rest is the original's: the list that holds the weight is carried whole
    for mine, theirs in zip(
        tuned.objectives["navigate"].terms, original.objectives["navigate"].terms
    ):
        assert (mine.term, mine.params) == (theirs.term, theirs.params)
    assert tuned.world == original.world and tuned.episode == original.episode
    held = holdout(
        target, path, TuneOptions(**{**opts.__dict__, "holdout": (5, 6)}), StandIn(), Events()
    )
    assert held.complete and held.original.trials == held.tuned.trials == 2
    text = report(target, space, opts, s, path, held)
    for part in ("## Trials", "## Parameter importances", "per seed", "Wilson", "overlay.yaml"):
        assert part in text


def tune_cli(tmp_path, monkeypatch, runner, *options):
    """``m3p2i tune navigation`` (2 trials on seeds 0-1 unless ``options`` say otherwise) with
    ``runner`` for the bench and no processes' ``--check``: the command in a second."""
    monkeypatch.setattr("m3p2i.process_checks.scenario_errors", lambda source: [])
    monkeypatch.setattr("m3p2i.tune.run.make_runner", lambda *args, **kwargs: runner)
    space = write_space(tmp_path, SPACE)
    args = ["tune", "navigation", "--space", str(space), "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, [*args, "--trials", "2", "--seeds", "0-1", *options])
    return result, " ".join(result.output.replace("│", " ").split())  # unwrapped from its box


def test_the_command_writes_the_overlay_the_report_and_the_held_out_rows(tmp_path, monkeypatch):
    runner = StandIn()
    result, output = tune_cli(tmp_path, monkeypatch, runner, "--holdout", "5")
    assert result.exit_code == 0, result.output
    assert "best: trial" in output and "held-out tuned: " in output
    assert len(runner.ran) == 2 * 2 + 2
    for name in ("overlay.yaml", "report.md", "holdout.csv"):
        assert (tmp_path / "out" / name).is_file()


@pytest.mark.parametrize(
    "option, value, expected",
    [
        ("--workers", "-1", "greater than or equal to 0"),
        ("--timeout", "-5", "-5: expected a finite number of seconds > 0"),
        ("--timeout", "0", "0: expected a finite number of seconds > 0"),
        ("--timeout", "nan", "nan: expected a finite number of seconds > 0"),
        ("--timeout", "inf", "inf: expected a finite number of seconds > 0"),
        ("--sampler-seed", "-1", "greater than or equal to 0"),
        ("--trials", "0", "greater than or equal to 1"),
        ("--cpus-per-trial", "0", "greater than or equal to 1"),
        ("--seeds", "-1-3", "not a seed range (got '-1-3'; expected A-B (A <= B"),
        ("--holdout", "9-5", "not a seed range (got '9-5'; expected A-B (A <= B"),
        ("--holdout", "", "not a seed range (got ''; expected A-B (A <= B"),  # was: no holdout
    ],
)
def test_a_numeric_option_out_of_range_is_refused_before_anything_runs(
    tmp_path, monkeypatch, option, value, expected
):
    """Not ``--workers -1`` running nothing and dividing by zero, nor ``--timeout -5`` timing
    every episode out: exit 2 naming the option and what it takes (typer's range messages
    leave the value out)."""
    runner = StandIn()
    result, output = tune_cli(tmp_path, monkeypatch, runner, option, value)
    assert result.exit_code == 2, result.output
    assert option in output and expected in output, output
    assert runner.ran == [] and not (tmp_path / "out").exists()


def test_a_study_in_which_no_trial_finished_names_no_best_trial(tmp_path, monkeypatch):
    """Every episode past its time-out (no outcome): the study says so and exits 1, with no
    best trial, overlay or report made from no data."""
    runner = StandIn(reason="timeout")
    result, output = tune_cli(tmp_path, monkeypatch, runner, "--holdout", "5")
    assert result.exit_code == 1, result.output
    assert "no trial finished" in output and "timeout: 4" in output, output
    assert "best: trial" not in output
    assert len(runner.ran) == 2 * 2  # the study ran; the held-out seeds did not
    for name in ("overlay.yaml", "report.md", "holdout.csv"):
        assert not (tmp_path / "out" / name).exists()


def test_a_bad_scenario_key_is_the_loaders_error_before_any_trial(tmp_path):
    space = write_space(tmp_path, {"params": {"planner.sampels": {"low": 10, "high": 20}}})
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["tune", "navigation", "--space", str(space), "--trials", "2", "--out", str(out)]
    )
    assert result.exit_code == 2
    assert "planner.sampels: unknown key" in result.output
    assert "navigation.yaml" in result.output and str(space) in result.output
    assert not (out / "study.db").exists() and not (out / "results.csv").exists()
    # a value out of the loader's range: its own message, naming the value
    space = write_space(tmp_path, {"params": {"planner.samples": {"low": -5, "high": 20}}})
    target = resolve_target("navigation")
    with pytest.raises(ConfigError, match=r"planner.samples.*-5"):
        check_space(target, load_space(space), tmp_path / "v")


@pytest.mark.parametrize(
    "data, where, message",
    [
        ({}, "params", "missing required key"),
        (
            {"params": {"planner.samples": {"low": 50, "high": 20}}},
            "params.planner.samples.high",
            "must be above low",
        ),
        (
            {"params": {"planner.samples": {"low": 0, "high": 20, "log": True}}},
            "params.planner.samples.low",
            "log scale",
        ),
        (
            {"params": {"planner.samples": {"low": 1, "hgh": 20}}},
            "params.planner.samples.high",
            "missing",
        ),
        (
            {"params": {"planner.samples": {"low": 1, "high": 20, "scale": 2}}},
            "params.planner.samples.scale",
            "unknown key",
        ),
        (
            {"params": {"planner..samples": {"low": 1, "high": 2}}},
            "params.planner..samples",
            "not a scenario key",
        ),
        (
            {"params": {"planner.samples": {"choices": []}}},
            "params.planner.samples.choices",
            "at least one",
        ),
        (
            {"params": {"planner.samples": {"low": "a", "high": 2}}},
            "params.planner.samples.low",
            "'a'",
        ),
        ({"params": {"planner.samples": [1, 2]}}, "params.planner.samples", "must be a mapping"),
        (
            {"params": {"planner.samples": {"choices": [1]}}, "objective": {"speed": 1}},
            "objective.speed",
            "unknown key",
        ),
    ],
)
def test_a_malformed_space_names_file_key_and_value(tmp_path, data, where, message):
    path = write_space(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_space(path)
    assert str(path) in str(err.value) and where in str(err.value) and message in str(err.value)


def test_seed_ranges_and_targets():
    assert parse_seeds("0-3", "--seeds") == (0, 1, 2, 3)
    assert parse_seeds("5,0-1,1", "--seeds") == (5, 0, 1)
    for bad in ("3-1", "a", "1-", "", "0-4294967296", "0-10000", "0-9999,20000"):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad, "--seeds")
    assert len(parse_seeds("0-9999", "--seeds")) == 10_000  # the most a study takes
    case = resolve_target("robustness:push_lab_comp")
    assert case.case.faults == "lab" and case.case.delays is not None and case.base == "push"
    assert resolve_target("push_lab_comp").case == case.case  # a case name of one bench file
    with pytest.raises(ConfigError, match="no such case"):
        resolve_target("robustness:nope")


@pytest.mark.slow
def test_the_shipped_example_writes_an_overlay_that_m3p2i_run_runs(tmp_path):
    """The docs' example, smaller (2 trials on one seed, one held-out seed): real episodes, the
    overlay, the report, and ``m3p2i run`` of the overlay. (Resuming: the stand-in tests.)"""
    out = tmp_path / "tuned"
    example = Path(__file__).resolve().parents[2] / "configs" / "tune" / "navigation.yaml"
    args = ["-m", "m3p2i", "tune", "navigation", "--space", str(example)]
    args += ["--trials", "2", "--seeds", "0", "--holdout", "1", "--out", str(out)]
    tuned = subprocess.run([sys.executable, *args], capture_output=True, text=True)
    assert tuned.returncode == 0, tuned.stdout + tuned.stderr
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 + 2  # two trials on seed 0, original and tuned on seed 1
    assert all(r["success"] == "1" for r in rows), rows
    assert "## Held-out evaluation" in (out / "report.md").read_text()
    with (out / "holdout.csv").open() as f:  # the held-out rows alone, for m3p2i report
        held = list(csv.DictReader(f))
    assert [(r["case"], r["seed"]) for r in held] == [
        ("navigation", "1"),
        ("navigation_tuned", "1"),
    ]
    run = subprocess.run(
        [sys.executable, "-m", "m3p2i", "run", str(out / "overlay.yaml")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "success" in run.stdout


def test_without_optuna_the_error_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "optuna", None)  # import optuna raises ImportError
    space = write_space(tmp_path, SPACE)
    result = CliRunner().invoke(
        app, ["tune", "navigation", "--space", str(space), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 2
    assert "m3p2i tune needs Optuna: pip install 'm3p2i[tune]'" in result.output
