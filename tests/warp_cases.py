"""Start states and control sequences on which the warp backend is compared with
mujoco.rollout (tests/planner_client/test_warp_backend.py): smooth motion and contact-rich
motion for navigation, push_pull and pick_place."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from planner_client.model_state import get_full_state
from planner_client.problem import PlanningProblem, build_problem
from shared.scenario import load_scenario
from shared.scene import initial_data


@dataclass
class Case:
    problem: PlanningProblem
    x0: np.ndarray  # [nstate] full physics state
    control: np.ndarray  # [S, T, nu]
    mocap: tuple[np.ndarray, np.ndarray]


def _controls(
    model: mujoco.MjModel,
    samples: int,
    horizon: int,
    seed: int,
    toward: dict[int, float] | None = None,
) -> np.ndarray:
    """Random controls in the actuators' ranges; channels in ``toward`` held at that value for
    the first half of the samples (driving into an obstacle)."""
    rng = np.random.default_rng(seed)
    lo, hi = model.actuator_ctrlrange.T
    u = rng.uniform(lo, hi, size=(samples, horizon, model.nu))
    for ch, v in (toward or {}).items():
        u[: samples // 2, :, ch] = v
    return u


def case(scenario: str, contact: bool, samples: int = 16, seed: int = 0) -> Case:
    """``contact=False``: from the scenario's start state, random controls. ``contact=True``:
    the robot placed just short of an obstacle (navigation: block_a; push_pull: the box) and
    half the samples driving into it; for pick_place the start state itself has contacts (the
    cubes resting on the table) and the arm reaches down toward them."""
    sc = load_scenario(scenario)
    problem = build_problem(sc)
    m = problem.model
    d = initial_data(sc, m)
    toward = None
    if contact and scenario == "navigation":
        d.qpos[:2] = (-0.75, 1.5)  # 0.35 m east of block_a's face at x = -1.1
        toward = {0: m.actuator_ctrlrange[0, 0]}  # full speed west
    elif contact and scenario == "push_pull":
        box = m.body("box").jntadr[0]
        d.qpos[:2] = d.qpos[m.jnt_qposadr[box]] - 0.45, d.qpos[m.jnt_qposadr[box] + 1]
        toward = {0: m.actuator_ctrlrange[0, 1]}  # full speed east, into the box
    elif contact and scenario == "pick_place":
        toward = {1: m.actuator_ctrlrange[1, 1], 3: m.actuator_ctrlrange[3, 1]}  # reach down
    mujoco.mj_forward(m, d)
    x0 = get_full_state(m, d).copy()
    control = _controls(m, samples, sc.planner.horizon, seed, toward)
    return Case(problem, x0, control, (d.mocap_pos.copy(), d.mocap_quat.copy()))


def deviation(problem: PlanningProblem, a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """Largest |a - b| of each sensor kind over samples and steps (``[S, T, nsensordata]``)."""
    out: dict[str, float] = {}
    for req, cols in problem.columns.spans.items():
        err = float(np.abs(a[..., cols] - b[..., cols]).max())
        out[req.kind] = max(out.get(req.kind, 0.0), err)
    return out
