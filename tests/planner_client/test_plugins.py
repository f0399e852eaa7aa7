"""The user's cost terms: a module outside the package, named by the scenario (``plugins:``) or by
the operator (``m3p2i-planner --plugins``), registers terms with the package's decorator and
drives a scenario; only the planner imports it, never on a scenario received over the wire; a
missing module, a failing one and a term registered twice are clear errors."""

from __future__ import annotations

import functools
import sys

import mujoco
import pytest
import yaml
from typer.testing import CliRunner

from planner_client import planner_check
from planner_client import plugins as P
from planner_client.build import build_controller
from planner_client.cli import app as planner_app
from planner_client.costs import TERMS
from planner_client.observers import SymbolicObserver
from planner_client.problem import build_problem
from server.inprocess import run_episode
from shared.config import ConfigError
from shared.predicates import PREDICATES, PluginPredicate
from shared.scenario import SCENARIO_DIR, load_scenario
from tests.user_folder import reach, user_folder

# a squared distance between two frames: the docs' worked example (docs/cost_terms.md)
MY_TERMS = """
from dataclasses import dataclass

from planner_client.costs import CostTerm, register
from planner_client.sensors import SensorRequest


@register("{name}")
@dataclass
class SquaredDistance(CostTerm):
    a: str
    b: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), b=ctx.frame(s, "b"))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.b)]

    def __call__(self, batch):
        pa, pb = (batch.get(r) for r in self.requests)
        return ((pa - pb) ** 2).sum(-1)
"""


# an observer of the user's: the tip within a radius of a frame
MY_PREDICATES = """
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from shared.predicates import Predicate, register


@register("tip_within")
@dataclass(frozen=True)
class TipWithin(Predicate):
    a: str
    b: str
    radius: float
    frame_keys: ClassVar[tuple[str, ...]] = ("a", "b")

    @classmethod
    def from_section(cls, s):
        return cls(a=s.req("a", str), b=s.req("b", str), radius=s.req("radius", float))

    def holds(self, view, frames):
        d = frames["a"].pos(view.data) - frames["b"].pos(view.data)
        return float(np.linalg.norm(d)) <= self.radius
"""


@pytest.fixture(autouse=True)
def fresh_registry():
    """Each test's plugins leave the registries and the module cache as they were."""
    terms, preds, files, modules = dict(TERMS), dict(PREDICATES), dict(P._BY_FILE), set(sys.modules)
    yield
    TERMS.clear()
    TERMS.update(terms)
    PREDICATES.clear()
    PREDICATES.update(preds)
    P._BY_FILE.clear()
    P._BY_FILE.update(files)
    for name in set(sys.modules) - modules:
        if name.startswith("m3p2i_plugin_"):
            del sys.modules[name]


def _terms(name: str) -> list[dict]:
    return [
        {"term": name, "a": "robot", "b": "target", "weight": 4.0},
        {"term": name, "a": "robot", "b": "target", "weight": 16.0, "when": "terminal"},
    ]


def lab(tmp_path, term: str = "squared_reach", **extra):
    """The user's folder with the plugin beside the scenario, which uses only the plugin's term."""
    path = user_folder(tmp_path, scenario=reach(terms=_terms(term), **extra))
    (path.parent / "my_terms.py").write_text(MY_TERMS.format(name=term))
    return path


def test_a_term_of_the_users_module_drives_a_scenario_from_the_users_folder(tmp_path):
    path = lab(tmp_path, plugins=["my_terms"])
    planner = functools.partial(build_controller, threads=2)
    for seed in range(2):
        result = run_episode(path, planner, seed=seed)
        assert result.status == "success", (seed, result.summary)
    assert TERMS["squared_reach"].__module__.startswith("m3p2i_plugin_my_terms_")


def test_only_the_planner_imports_the_plugins(tmp_path):
    # the world reads the same file and imports nothing of it (a bridge's computer needs none)
    path = lab(tmp_path, "only_planner", plugins=["my_terms.py"])
    sc = load_scenario(path)
    assert sc.plugins == ("my_terms.py",) and "only_planner" not in TERMS
    build_problem(sc)
    assert "only_planner" in TERMS


def test_a_scenario_without_its_plugin_names_the_unknown_term_and_the_way(tmp_path):
    with pytest.raises(
        ConfigError, match=r"unknown cost term.*plugins: or the planner's --plugins"
    ):
        build_problem(load_scenario(lab(tmp_path, "not_imported")))


def test_m3p2i_planner_plugins_imports_the_operators_module(tmp_path, monkeypatch):
    path = lab(tmp_path, "from_the_command_line")
    monkeypatch.chdir(path.parent)
    args = ["--scenario", str(path), "--check"]
    refused = CliRunner().invoke(planner_app, args)
    assert refused.exit_code == 2 and "unknown cost term" in refused.output
    accepted = CliRunner().invoke(planner_app, [*args, "--plugins", "my_terms.py"])
    assert accepted.exit_code == 0, accepted.output


def test_a_missing_plugin_is_named_with_where_it_was_looked_for(tmp_path):
    path = lab(tmp_path, plugins=["my_term"])
    with pytest.raises(ConfigError) as exc:
        build_problem(load_scenario(path))
    text = str(exc.value)
    assert "reach.yaml: plugins[0]: no such plugin module (got 'my_term'" in text
    assert str(path.parent) in text


def test_a_failing_plugin_says_what_failed_and_where(tmp_path):
    path = lab(tmp_path, plugins=["my_terms", "broken"])
    (path.parent / "broken.py").write_text("import math\n\nSCALE = 1 / 0\n")
    with pytest.raises(ConfigError) as exc:
        build_problem(load_scenario(path))
    text = str(exc.value)
    assert "plugins[1]: importing the plugin failed: ZeroDivisionError: division by zero" in text
    assert "broken.py:3" in text and "SCALE = 1 / 0" in text


def test_a_plugin_that_needs_a_missing_library_is_not_called_missing(tmp_path):
    path = lab(tmp_path, plugins=["needs_lib"])
    (path.parent / "needs_lib.py").write_text("import no_such_library_m3p2i\n")
    with pytest.raises(ConfigError, match="failed: ModuleNotFoundError: No module named"):
        build_problem(load_scenario(path))


def test_a_term_registered_twice_names_both(tmp_path):
    path = lab(tmp_path, "distance", plugins=["my_terms"])  # a shipped term's name
    with pytest.raises(ConfigError) as exc:
        build_problem(load_scenario(path))
    text = str(exc.value)
    assert "cost term 'distance' registered twice" in text
    assert "planner_client.costs.poses.Distance" in text and "SquaredDistance" in text


def test_plugins_are_names(tmp_path):
    assert load_scenario(lab(tmp_path, plugins="my_terms")).plugins == ("my_terms",)
    with pytest.raises(ConfigError, match=r"plugins: wrong type .*a list of Python modules"):
        load_scenario(lab(tmp_path, plugins=[3]))


def test_a_ray_node_refuses_a_received_scenario_that_names_plugins(tmp_path):
    pytest.importorskip("ray", reason="needs the cluster extra")
    from m3p2i import bench_ray as BR
    from m3p2i.bench import BenchCase

    raw = yaml.safe_load((SCENARIO_DIR / "navigation.yaml").read_text())
    path = tmp_path / "navigation.yaml"  # a shipped robot: a node has it
    path.write_text(yaml.safe_dump({**raw, "plugins": ["my_terms"]}))
    (tmp_path / "my_terms.py").write_text(MY_TERMS.format(name="from_the_driver"))
    task = BR.TrialTask(
        BenchCase("navigation", "normal", str(path), 1),
        path.name,
        path.read_text(),
        load_scenario(path).hash,
        0,
        {},
        60.0,
        1,
    )
    row, files = BR.remote_trial(task)
    assert row["status"] == "failure" and "a node imports no module" in row["reason"]
    assert files == {} and not any(n.startswith("m3p2i_plugin_") for n in sys.modules)


def observed(tmp_path, observer: dict, **extra):
    """The reaching scenario as a task whose one factor an observer of the user's watches."""
    task = {
        "task": {
            "factors": {
                "tip": {
                    "states": ["at_target", "away"],
                    "actions": {"reach_target": {"effect": {"set": "at_target"}}},
                }
            },
            "goals": {"tip": "at_target"},
        },
        "observers": {"tip": observer},
        "plan": {"reach_target": "reach"},
        "modes": None,
    }
    path = user_folder(tmp_path, scenario={**reach(**extra), **task})
    raw = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump({k: v for k, v in raw.items() if v is not None}))
    (path.parent / "my_predicates.py").write_text(MY_PREDICATES)
    return path


TIP = {"tip_within": {"a": "robot", "b": "target", "radius": 0.03}}


def test_an_observer_of_the_users_module_watches_the_task(tmp_path):
    path = observed(tmp_path, TIP, plugins=["my_predicates"])
    sc = load_scenario(path)  # as the world reads it: nothing imported, nothing evaluated
    (rule,) = sc.observers["tip"].rules
    assert isinstance(rule[1], PluginPredicate) and "tip_within" not in PREDICATES
    problem = build_problem(sc)  # the planner imports the scenario's plugins
    observer = SymbolicObserver(sc.observers, problem.resolve)
    data = mujoco.MjData(problem.model)
    data.qpos[:2] = sc.robot.qpos
    mujoco.mj_forward(problem.model, data)
    assert observer(data, {}) == {"tip": "away"}
    data.mocap_pos[0] = data.site("tip").xpos  # the target where the tip is
    mujoco.mj_forward(problem.model, data)
    assert observer(data, {}) == {"tip": "at_target"}
    result = run_episode(path, functools.partial(build_controller, threads=2), seed=0)
    assert result.status == "success", result.summary


def test_an_unknown_observer_is_refused_by_the_planner_naming_plugins(tmp_path):
    typo = {"tip_withn": TIP["tip_within"]}
    path = observed(tmp_path, typo, plugins=["my_predicates"])
    errors = "\n".join(str(e) for e in planner_check.scenario_errors(path))
    assert "observers.tip.tip_withn: unknown predicate" in errors and "plugins:" in errors
    # without plugins: the scenario names no module, so the name is wrong at load, as before
    with pytest.raises(ConfigError, match=r"observers\.tip\.tip_withn: unknown predicate"):
        load_scenario(observed(tmp_path / "none", typo))


def test_the_success_test_keeps_the_packages_predicates(tmp_path):
    # the world judges success and imports no plugin
    path = observed(tmp_path, TIP, plugins=["my_predicates"])
    raw = yaml.safe_load(path.read_text())
    raw["episode"]["success"] = [TIP]
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match=r"episode\.success.*unknown predicate"):
        load_scenario(path)
