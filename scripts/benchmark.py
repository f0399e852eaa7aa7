"""Planner speed: iterations per second, and the ratio of one iteration to a bare rollout.

For each scenario the planner runs closed loop in-process (its u0 applied to a copy of the world)
and each iteration (sample -> mujoco.rollout -> costs -> M3P2I update) is timed. The physical limit
is one bare ``mujoco.rollout`` of the same S x T steps of the world model (no planner sensors, same
thread count, persistent pool); ``ratio_to_rollout`` = iteration time / that.

    python scripts/benchmark.py                      # table
    python scripts/benchmark.py --json               # one JSON object per line per case
    python scripts/benchmark.py -s navigation -n 300
"""

from __future__ import annotations

import json
import os
import time

import mujoco
import numpy as np
import typer
from mujoco import rollout as mj_rollout
from rich.console import Console
from rich.table import Table

from shared.scenario import load_scenario
from shared.scene import compile_model, get_full_state
from planner_client.build import build_motion_planner

CASES = {"navigation": {}}   # scenario -> overrides of planner samples/horizon

app = typer.Typer(add_completion=False)


def bare_rollout_time(model: mujoco.MjModel, samples: int, horizon: int, nthread: int,
                      repeats: int) -> float:
    """Median seconds of one mujoco.rollout of [samples, horizon] random controls."""
    data = [mujoco.MjData(model) for _ in range(nthread)]
    d0 = mujoco.MjData(model)
    mujoco.mj_forward(model, d0)
    x0 = np.tile(get_full_state(model, d0), (samples, 1))
    lo, hi = model.actuator_ctrlrange.T
    rng = np.random.default_rng(0)
    ctrl = rng.uniform(lo, hi, size=(samples, horizon, model.nu))
    times = []
    with mj_rollout.Rollout(nthread=nthread) as pool:
        for _ in range(repeats + 3):
            t = time.perf_counter()
            pool.rollout(model, data, x0, ctrl, nstep=horizon)
            times.append(time.perf_counter() - t)
    return float(np.median(times[3:]))


def planner_times(scenario, iterations: int, threads: int) -> tuple[list[float], int, int]:
    planner = build_motion_planner(scenario, threads)
    model = planner.problem.model
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    times = []
    try:
        for _ in range(iterations + 5):
            x0 = get_full_state(model, data)
            t = time.perf_counter()
            plan = planner.plan(x0)
            times.append(time.perf_counter() - t)
            data.ctrl[:] = plan.result.u0.numpy()
            mujoco.mj_step(model, data)
        samples = planner.mppi.num_samples
    finally:
        planner.close()
    return times[5:], samples, scenario.planner.horizon


@app.command()
def main(
    scenario: list[str] = typer.Option(list(CASES), "--scenario", "-s", help="Scenarios to run."),
    iterations: int = typer.Option(200, "--iterations", "-n", help="Timed planner iterations."),
    threads: int = typer.Option(0, help="Rollout threads (0: one per core)."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line per case."),
) -> None:
    nthread = threads or os.cpu_count() or 1
    rows = []
    for name in scenario:
        sc = load_scenario(name)
        times, samples, horizon = planner_times(sc, iterations, nthread)
        iteration = float(np.median(times))
        bare = bare_rollout_time(compile_model(sc), samples, horizon, nthread, iterations)
        row = {"scenario": sc.name, "samples": samples, "horizon": horizon,
               "hz": round(1.0 / iteration, 2), "ratio_to_rollout": round(iteration / bare, 3),
               "iteration_ms": round(iteration * 1e3, 3), "rollout_ms": round(bare * 1e3, 3),
               "threads": nthread}
        rows.append(row)
        if as_json:
            print(json.dumps(row), flush=True)
    if not as_json:
        table = Table(title=f"planner speed ({nthread} rollout threads, median of {iterations})")
        for col in ("scenario", "samples x horizon", "planner Hz", "iteration ms",
                    "bare rollout ms", "ratio"):
            table.add_column(col, justify="right")
        for r in rows:
            table.add_row(r["scenario"], f"{r['samples']} x {r['horizon']}", f"{r['hz']:.1f}",
                          f"{r['iteration_ms']:.2f}", f"{r['rollout_ms']:.2f}",
                          f"{r['ratio_to_rollout']:.2f}")
        Console().print(table)


if __name__ == "__main__":
    app()
