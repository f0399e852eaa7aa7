"""What a planner's rollout costs, part by part: its bare ``mujoco.rollout`` with parts of the
physics switched off, and the planner rates those times allow.

The rollout is a planner's floor (``scripts/benchmark.py``): an iteration at 1.2 times it runs at
``1 / (1.2 · rollout)``. This times the planner's own model (its ``planner.model`` and
``planner.timestep``) over ``--samples`` × ``--horizon`` random controls from the scenario's
start state, as it is and with MuJoCo's disable flags for its sensors, its contacts and all of
its constraints, in alternating rounds on one persistent thread pool. A model with no contacts
and no constraints is what no tuning of the contact model can go below: if its rate at 1.2
misses a target, the target needs fewer or cheaper steps, not a cheaper contact model.

    python scripts/rollout_floor.py -s navigation -s push_pull_fast --samples 400 --horizon 15

(a thin command over :func:`floor_table`). A measuring tool, not a part of the planner's loop.
"""

from __future__ import annotations

import copy
import statistics
import time

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout
from rich.table import Table

from planner_client.model_state import get_full_state
from planner_client.problem import build_problem
from shared.scenario import load_scenario
from shared.scene import initial_data

_FLAGS = mujoco.mjtDisableBit
VARIANTS = {
    "as planned": 0,
    "no sensors": int(_FLAGS.mjDSBL_SENSOR),
    "no contacts": int(_FLAGS.mjDSBL_CONTACT),
    "no constraints": int(_FLAGS.mjDSBL_CONSTRAINT),
}


def measure(name: str, samples: int, horizon: int, nthread: int, rounds: int) -> dict[str, float]:
    """Median seconds of one bare rollout of ``samples`` × ``horizon`` per variant."""
    scenario = load_scenario(name)
    model = build_problem(scenario).model  # the planner's own model and sensors
    x0 = get_full_state(model, initial_data(scenario, model)).copy()
    sigma = 0.5 * (model.actuator_ctrlrange[:, 1] - model.actuator_ctrlrange[:, 0])
    sigma = np.where(model.actuator_ctrllimited > 0, sigma, 1.0)
    ctrl = np.random.default_rng(0).normal(0.0, 1.0, (samples, horizon, model.nu)) * sigma
    models = {}
    for variant, flags in VARIANTS.items():
        m = copy.copy(model)
        m.opt.disableflags |= flags
        models[variant] = m
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    times: dict[str, list[float]] = {v: [] for v in VARIANTS}
    with mj_rollout.Rollout(nthread=nthread) as pool:
        for r in range(rounds + 1):
            for variant, m in models.items():
                t = time.perf_counter()
                pool.rollout(m, datas, x0[None], ctrl, nstep=horizon)
                if r:  # round 0 warms threads and caches
                    times[variant].append(time.perf_counter() - t)
    return {v: statistics.median(t) for v, t in times.items()}


def floor_table(
    scenarios: list[str], samples: int, horizon: int, nthread: int, rounds: int
) -> Table:
    """One row per scenario and variant: the rollout's time, per step, and the planner rates it
    allows at ratio 1 and 1.2."""
    table = Table(
        title=f"bare rollouts of {samples} x {horizon} on {nthread} threads (median of {rounds})"
    )
    for col in (
        "scenario",
        "variant",
        "rollout ms",
        "µs per step",
        "Hz at ratio 1",
        "Hz at ratio 1.2",
    ):
        table.add_column(col, justify="right")
    for name in scenarios:
        for variant, sec in measure(name, samples, horizon, nthread, rounds).items():
            table.add_row(
                name,
                variant,
                f"{sec * 1e3:.2f}",
                f"{sec * 1e6 / (samples * horizon):.2f}",
                f"{1 / sec:.1f}",
                f"{1 / (1.2 * sec):.1f}",
            )
    return table
