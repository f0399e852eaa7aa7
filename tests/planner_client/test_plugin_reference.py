"""The plugin author's reference (docs/cost_terms.md, "Your own cost terms"): its complete
example, docs/examples/lab_terms.py, is the code the page shows and drives the lab's arm through
a scenario's ``plugins:``; the ``jointvel`` sensor it reads is the joint's velocity along the
planner's rollouts."""

from __future__ import annotations

import functools
import json
import re
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from planner_client import plugins as P
from planner_client.backends.mujoco_pool import MujocoPoolBackend
from planner_client.build import build_controller
from planner_client.costs import TERMS
from planner_client.model_state import get_full_state
from planner_client.problem import build_problem
from planner_client.sensors import SensorRequest
from server.inprocess import run_episode
from shared.scenario import load_scenario
from shared.scene import initial_data
from tests.user_folder import DISTANCE_TERMS, reach, user_folder

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "docs" / "examples" / "lab_terms.py"


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


def test_the_page_shows_the_example_file_as_it_is():
    page = (ROOT / "docs" / "cost_terms.md").read_text(encoding="utf-8")
    blocks = re.findall(r"^```python\n(.*?)^```", page, re.S | re.M)
    assert EXAMPLE.read_text(encoding="utf-8") in blocks
    assert "docs/examples/lab_terms.py" in page


def test_jointvel_reads_the_joint_velocity_along_rollouts(tmp_path):
    sc = load_scenario(user_folder(tmp_path))
    vel, pos = (SensorRequest(kind, "shoulder") for kind in ("jointvel", "jointpos"))
    problem = build_problem(sc, extra_sensors=[vel, pos])
    model = problem.model
    data = initial_data(sc, model)
    controls = np.array([[[0.8, -0.5]] * 6, [[-1.2, 0.3]] * 6])  # [S, T, nu]
    rollouts = MujocoPoolBackend(model, 1)
    try:
        sd = rollouts.sensors(get_full_state(model, data), torch.from_numpy(controls))
        v, q = (problem.columns.take(sd, r)[..., 0].numpy() for r in (vel, pos))
    finally:
        rollouts.close()
    dof = model.joint("shoulder").dofadr[0]
    for s, plan in enumerate(controls):
        d = initial_data(sc, model)
        seen = []
        for u in plan:  # a step's values are those of the state its control acts on
            seen.append(d.qvel[dof])
            d.ctrl[:] = u
            mujoco.mj_step(model, d)
        np.testing.assert_allclose(v[s], seen, rtol=0, atol=1e-12)
    assert np.abs(v[:, 1:]).min() > 0.1  # the joint turns: a velocity, not a zero column
    # implicit integration: each step moves the joint by dt times the next step's velocity
    np.testing.assert_allclose(np.diff(q, axis=1), model.opt.timestep * v[:, 1:], atol=1e-12)


def _max_speed(log: Path) -> float:
    steps = [json.loads(line) for line in log.read_text().splitlines()]
    return max(abs(v) for r in steps if r.get("kind") == "step" for v in r["qvel"])


def test_the_example_plugin_drives_the_arm_slower(tmp_path):
    """The lab's arm reaches its target with the distance terms alone, its joints turning
    faster than 0.6 rad/s, and again with the example's terms added through ``plugins:`` (the
    file loaded where it lies), never that fast."""
    slow = [
        {"term": "joint_speed", "joints": ["shoulder", "elbow"], "limit": 0.6, "weight": 5.0},
        {"term": "command_change", "weight": 0.1},
    ]
    speeds = []
    for name, terms, plugins in (
        ("fast", DISTANCE_TERMS, []),
        ("slow", DISTANCE_TERMS + slow, [str(EXAMPLE)]),
    ):
        path = user_folder(tmp_path / name, scenario=reach(terms=terms, plugins=plugins))
        result = run_episode(
            path,
            functools.partial(build_controller, threads=2),
            seed=0,
            log_path=tmp_path / f"{name}.jsonl",
        )
        assert result.status == "success", (name, result.summary)
        speeds.append(_max_speed(result.log_path))
    fast, slow_speed = speeds
    assert slow_speed < 0.6 < fast, speeds
    assert TERMS["joint_speed"].__module__.startswith("m3p2i_plugin_lab_terms_")
