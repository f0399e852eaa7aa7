"""A user's cost term that returns the wrong thing (a tensor of the wrong shape or dtype, a Python
float, a numpy array) or raises is refused before anything plans: ``m3p2i check`` and the
planner's start-up evaluate every term once on a small batch and name the term, its plugin module
and its objective, instead of a bare torch error mid-episode. A term returning ``[S, T]`` float64
passes, NaN included (a diverged rollout's cost: the planner gives it zero weight)."""

from __future__ import annotations

import sys

import pytest
from typer.testing import CliRunner

from m3p2i.cli import app
from planner_client import plugins as P
from planner_client.build import build_client, build_controller
from planner_client.costs import TERMS
from shared.config import ConfigError
from shared.endpoints import Endpoints
from shared.scenario import load_scenario
from tests.user_folder import DISTANCE_TERMS, reach, user_folder

# one term class per way of returning: the squared distance of the docs' example, returned as
TERM = """

@register("{name}")
@dataclass
class {cls}(CostTerm):
    a: str
    b: str

    @classmethod
    def from_params(cls, s, ctx):
        return cls(a=ctx.frame(s, "a"), b=ctx.frame(s, "b"))

    def sensors(self):
        return [SensorRequest("framepos", self.a), SensorRequest("framepos", self.b)]

    def __call__(self, batch):
        pa, pb = (batch.get(r) for r in self.requests)
        {body}
"""

HEAD = """
from dataclasses import dataclass

import torch

from planner_client.costs import CostTerm, register
from planner_client.sensors import SensorRequest
"""

# name: (the body of __call__, what the error says of it); the reach scenario plans 8 steps
BAD = {
    "per_axis": ("return (pa - pb) ** 2", "returned a tensor of shape [2, 8, 3]"),
    "per_sample": ("return ((pa - pb) ** 2).sum((-2, -1))", "returned a tensor of shape [2]"),
    "python_float": ("return 0.5", "returned a float, not a torch.Tensor"),
    "numpy_array": (
        "return ((pa - pb) ** 2).sum(-1).numpy()",
        "returned a numpy.ndarray, not a torch.Tensor",
    ),
    "single": ("return ((pa - pb) ** 2).sum(-1).float()", "returned a tensor of dtype float32"),
    "integer": ("return ((pa - pb) ** 2).sum(-1).long()", "returned a tensor of dtype int64"),
    "raises": ("return pa[..., 5]", "raised IndexError: index 5 is out of bounds"),
}
GOOD = {
    "squared": "return ((pa - pb) ** 2).sum(-1)",
    "not_a_number": "return torch.full(pa.shape[:-1], torch.nan, dtype=pa.dtype)",
}


@pytest.fixture(autouse=True)
def fresh_registry():
    """Each test's plugins leave the term registry and the module cache as they were."""
    terms, files, modules = dict(TERMS), dict(P._BY_FILE), set(sys.modules)
    yield
    TERMS.clear()
    TERMS.update(terms)
    P._BY_FILE.clear()
    P._BY_FILE.update(files)
    for name in set(sys.modules) - modules:
        if name.startswith("m3p2i_plugin_"):
            del sys.modules[name]


def lab(tmp_path, bodies: dict[str, str]):
    """The user's folder: ``lab_terms.py`` with a term per body, each the one term of an
    objective of its own name; the scenario plans with the shipped distance terms."""
    objectives = {
        "reach": {"terms": DISTANCE_TERMS},
        **{
            name: {"terms": [{"term": name, "a": "robot", "b": "target", "weight": 2.0}]}
            for name in bodies
        },
    }
    path = user_folder(tmp_path, scenario=reach(plugins=["lab_terms"], objectives=objectives))
    code = HEAD + "".join(
        TERM.format(name=name, cls=name.title().replace("_", ""), body=body)
        for name, body in bodies.items()
    )
    (path.parent / "lab_terms.py").write_text(code)
    return path


def _expected(path, name: str, said: str) -> str:
    cls = name.title().replace("_", "")
    return (
        f"{path}: objectives.{name}.terms[0]: cost term '{name}' of objective '{name}' "
        f"({cls} in plugin {path.parent / 'lab_terms.py'}) {said}"
    )


def test_m3p2i_check_evaluates_every_term_and_names_each_that_returns_the_wrong_thing(tmp_path):
    path = lab(tmp_path, {name: body for name, (body, _) in BAD.items()} | GOOD)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())  # the report wraps long lines
    for name, (_, said) in BAD.items():
        assert _expected(path, name, said) in text, (name, text)
    assert "expected a torch.Tensor [S, T] = [2, 8] of float64 on cpu" in text
    assert f"{len(BAD)} errors" in text
    for name in GOOD:
        assert f"'{name}'" not in text


def test_m3p2i_check_passes_a_term_that_returns_a_cost_per_sample_and_step(tmp_path):
    result = CliRunner().invoke(app, ["check", str(lab(tmp_path, GOOD))])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("name", BAD)
def test_the_planner_refuses_at_start_up_before_it_connects(tmp_path, name):
    path = lab(tmp_path, {name: BAD[name][0]})
    connected = []
    with pytest.raises(ConfigError) as exc:
        build_client(
            load_scenario(path),
            Endpoints("127.0.0.1", 1),
            threads=2,
            before_connect=lambda: connected.append(True),
        )
    assert _expected(path, name, BAD[name][1]) in str(exc.value)
    assert not connected


def test_the_planner_builds_with_terms_that_return_a_cost_per_sample_and_step(tmp_path):
    controller = build_controller(lab(tmp_path, GOOD), threads=2)
    controller.close()
