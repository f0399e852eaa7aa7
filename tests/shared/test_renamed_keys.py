"""Keys renamed so that "estimate" names one thing (a value inferred online): ``planner.estimate``
is ``planner.tracking``, ``planner.delays.estimate`` is ``planner.delays.measure``, ``spread:
estimate`` is ``spread: identified``, a bench case's ``compensate: estimate`` is ``compensate:
measure`` and ``--estimate-delays`` is ``--measure-delays``. The old spellings read the same,
warn once naming the new one, and keep the scenario's hash (results resume)."""

from __future__ import annotations

import copy

import pytest
import typer
import yaml

import shared.config
from m3p2i.bench import load_bench
from m3p2i.cli import app as m3p2i_app
from planner_client.cli import app as planner_app
from shared.config import ConfigError, load_yaml
from shared.scenario import find_scenario, parse_scenario

TRACKING = {"object_velocities": "from_poses", "pose_filter": 0.3, "velocity_filter": 0.3}


@pytest.fixture(autouse=True)
def _warn_again(monkeypatch):
    monkeypatch.setattr(shared.config, "_WARNED", set())


def _with(raw: dict, *path_and_value) -> dict:
    out = copy.deepcopy(raw)
    *path, key, value = path_and_value
    node = out
    for p in path:
        node = node.setdefault(p, {})
    node[key] = value
    return out


@pytest.mark.parametrize(
    ("old", "new", "read"),
    [
        (("planner", "estimate", TRACKING), ("planner", "tracking", TRACKING), "tracking"),
        (
            ("planner", "delays", "estimate", True),
            ("planner", "delays", "measure", True),
            "delays",
        ),
    ],
)
def test_an_old_key_reads_as_the_new_one_warns_once_and_keeps_the_hash(old, new, read):
    raw = load_yaml(find_scenario("push"))
    now = parse_scenario(_with(raw, *new), "push.yaml")
    with pytest.warns(FutureWarning, match=r"planner\.\S*estimate \(in push.yaml\).*write"):
        before = parse_scenario(_with(raw, *old), "push.yaml")
    assert getattr(before.planner, read) == getattr(now.planner, read)
    assert before.hash == now.hash != parse_scenario(raw, "push.yaml").hash
    both = _with(_with(raw, *old), *new)
    with pytest.raises(ConfigError, match=r"push.yaml: planner\.\S*estimate: both"):
        parse_scenario(both, "push.yaml")


def test_spread_estimate_reads_as_identified_and_keeps_the_hash():
    raw = load_yaml(find_scenario("pull_lab_variants"))
    variants = raw["planner"]["model"]["variants"]
    assert variants["spread"] == "identified"
    old = _with(raw, "planner", "model", "variants", "spread", "estimate")
    with pytest.warns(FutureWarning, match="spread: estimate .* write spread: identified"):
        before = parse_scenario(old, "pull_lab_variants.yaml")
    now = parse_scenario(raw, "pull_lab_variants.yaml")
    assert before.planner.model.variants == now.planner.model.variants
    assert before.hash == now.hash
    assert (
        now.hash
        != parse_scenario(
            _with(raw, "planner", "model", "variants", "spread", "all"), "x.yaml"
        ).hash
    )


def test_an_unknown_key_names_only_the_new_spelling():
    raw = _with(load_yaml(find_scenario("push")), "planner", "trackin", {})
    with pytest.raises(ConfigError, match="unknown key") as info:
        parse_scenario(raw, "push.yaml")
    assert "tracking" in str(info.value) and "estimate" not in str(info.value)


def test_a_bench_case_compensate_estimate_reads_as_measure(tmp_path):
    bench = tmp_path / "bench.yaml"
    case = {"case": "a", "scenario": "navigation", "trials": 1, "faults": "lab"}
    cases = []
    for value in ("measure", "estimate"):
        bench.write_text(yaml.safe_dump({"cases": [{**case, "compensate": value}]}))
        if value == "estimate":
            with pytest.warns(FutureWarning, match="compensate: estimate.*compensate: measure"):
                cases.append(load_bench(bench).cases[0])
        else:
            cases.append(load_bench(bench).cases[0])
    assert cases[0] == cases[1] and cases[0].measure_delays


def test_dash_dash_estimate_delays_is_a_hidden_second_name():
    run = typer.main.get_command(m3p2i_app).commands["run"]
    planner = typer.main.get_command(planner_app)
    assert run.make_context("run", ["navigation", "--estimate-delays"]).params["estimate_delays"]
    ctx = planner.make_context("m3p2i-planner", ["-s", "navigation", "--estimate-delays"])
    assert ctx.params["estimate_delays"]
    for command in (run, planner):
        shown = {p.name: p.hidden for p in command.params}
        assert shown["estimate_delays"] and not shown["measure_delays"]
