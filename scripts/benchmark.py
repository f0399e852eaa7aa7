"""Planner speed: iterations per second, and the ratio of one iteration to a bare rollout.

For each scenario the planner runs closed loop in-process (its u0 applied to a copy of the world)
and each iteration (sample -> mujoco.rollout -> costs -> M3P2I update) is timed. The physical limit
is one bare ``mujoco.rollout`` of the same S x T steps of the world model (no planner sensors, same
thread count, persistent pool); ``ratio_to_rollout`` = iteration time / that. The same rollout of
the planner's model, with the sensors its costs read, is reported beside it
(``ratio_to_sensor_rollout``): the difference between the two is what the sensors cost.

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
from shared.scene import compile_model, get_full_state, initial_data
from planner_client.build import build_motion_planner

SCENARIOS = ("navigation", "push_pull", "pick_place")

app = typer.Typer(add_completion=False)


def measure(scenario, iterations: int, nthread: int, rounds: int = 4) -> dict:
    """Median planner iteration and median bare rollouts, measured in alternating blocks.

    The planner runs closed loop (its u0 applied to its own copy of the world). The bare rollouts
    replay exactly the planner's own work: the [S, T] samples and start states of its last
    iterations, on the world model (no planner sensors: the physical limit) and on the planner's
    model (with the sensors its costs read). Blocks alternate ``rounds`` times so background load
    hits all three alike; each pool is used only in its own block so idle threads never compete.
    """
    planner = build_motion_planner(scenario, nthread)
    model = planner.problem.model
    data = initial_data(scenario, model)      # the scenario's start pose (the Panda's ready pose)
    world = compile_model(scenario)
    samples, horizon = planner.mppi.num_samples, scenario.planner.horizon
    pool_data = [mujoco.MjData(world) for _ in range(nthread)]
    work: list[tuple[np.ndarray, np.ndarray]] = []     # (planner x0, samples) of recent iterations
    times: dict[str, list[float]] = {"plan": [], "world": [], "sensors": []}
    block = max(1, iterations // rounds)

    def timed(key, fn):
        for i in range(block + 3):
            t = time.perf_counter()
            fn()
            if i >= 3:                      # the first calls of a block warm caches and threads
                times[key].append(time.perf_counter() - t)

    def plan_step():
        x0 = get_full_state(model, data).copy()
        it = planner.iterate(x0)
        work.append((x0, planner.last_samples.copy()))
        del work[:-block]
        data.ctrl[:] = it.result.u0.numpy()
        mujoco.mj_step(model, data)

    counter = iter(range(10**9))

    def world_rollout():
        # sensors add no state, so the planner's x0 is a valid world state
        x0, ctrl = work[next(counter) % len(work)]
        pool.rollout(world, pool_data, x0[None], ctrl, nstep=horizon)

    def sensor_rollout():
        x0, ctrl = work[next(counter) % len(work)]
        planner.engine.run(x0, ctrl)

    try:
        with mj_rollout.Rollout(nthread=nthread) as pool:
            for _ in range(rounds):
                timed("plan", plan_step)
                timed("world", world_rollout)
                timed("sensors", sensor_rollout)
    finally:
        planner.close()
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {"scenario": scenario.name, "samples": samples, "horizon": horizon,
            "hz": round(1.0 / med["plan"], 2),
            "ratio_to_rollout": round(med["plan"] / med["world"], 3),
            "ratio_to_sensor_rollout": round(med["plan"] / med["sensors"], 3),
            "iteration_ms": round(med["plan"] * 1e3, 3), "rollout_ms": round(med["world"] * 1e3, 3),
            "sensor_rollout_ms": round(med["sensors"] * 1e3, 3), "threads": nthread}


@app.command()
def main(
    scenario: list[str] = typer.Option(list(SCENARIOS), "--scenario", "-s", help="Scenarios to run."),
    iterations: int = typer.Option(200, "--iterations", "-n", help="Timed planner iterations."),
    threads: int = typer.Option(0, help="Rollout threads (0: one per core)."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line per case."),
) -> None:
    nthread = threads or os.cpu_count() or 1
    rows = []
    for name in scenario:
        row = measure(load_scenario(name), iterations, nthread)
        rows.append(row)
        if as_json:
            print(json.dumps(row), flush=True)
    if not as_json:
        table = Table(title=f"planner speed ({nthread} rollout threads, median of {iterations})")
        for col in ("scenario", "samples x horizon", "planner Hz", "iteration ms",
                    "bare rollout ms", "ratio", "rollout + sensors ms", "ratio to it"):
            table.add_column(col, justify="right")
        for r in rows:
            table.add_row(r["scenario"], f"{r['samples']} x {r['horizon']}", f"{r['hz']:.1f}",
                          f"{r['iteration_ms']:.2f}", f"{r['rollout_ms']:.2f}",
                          f"{r['ratio_to_rollout']:.2f}", f"{r['sensor_rollout_ms']:.2f}",
                          f"{r['ratio_to_sensor_rollout']:.2f}")
        Console().print(table)


if __name__ == "__main__":
    app()
