"""Planner speed: iterations per second, and the ratio of one iteration to a bare rollout.

For each scenario the planner's control loop (:class:`planner_client.controller.Controller`, as
the planner process runs it) runs closed loop in-process, its command applied to a copy of the
world, and each iteration (mirror -> task layer -> sample -> mujoco.rollout -> costs -> M3P2I
update -> command: the planning time a world logs) is timed against bare ``mujoco.rollout`` calls
replaying the planner's own samples and start states (same thread count, persistent pool):

- ``ratio_to_rollout``: to the world model over the same horizon in seconds (each control held
  for ``planner.timestep / world.timestep`` world steps): what planning costs against simulating
  the world itself. Below 1 when the planner's own model (``planner.model``, ``planner.timestep``)
  is cheaper than the world's.
- ``ratio_to_own_rollout``: to the planner's own model (its options and timestep) without the
  sensors its costs read: what an iteration adds to its own bare rollout.
- ``ratio_to_sensor_rollout``: to the planner's own model with those sensors: the difference to
  the previous one is what the sensors cost.

    python scripts/benchmark.py                      # table
    python scripts/benchmark.py --json               # one JSON object per line per case
    python scripts/benchmark.py -s navigation -n 300
    python scripts/benchmark.py -s push_pull_fast --horizon 15   # its model over 15 steps

With ``--backend warp`` the planner rolls out with MuJoCo Warp (the m3p2i[gpu] extra) on
``--device`` (cuda:0, or cpu: slow, for machines without a GPU), and ``--samples`` sets the
samples per mode (a list runs each); ``rollout + sensors`` is then the MJWarp rollout, and the
bare rollout stays ``mujoco.rollout`` on the CPU cores, so ``ratio`` < 1 is a speed-up over it.
A scenario MJWarp cannot roll out is reported and skipped. The first run of a model compiles
MJWarp's kernels (minutes on a CPU; cached in ~/.cache/warp); untimed warm-up calls absorb it.

    python scripts/benchmark.py --backend warp --device cuda:0 --samples 1024,4096,16384

``--runs N`` repeats the whole measurement (the spread between runs is machine noise: other
processes, frequency scaling); ``--out FILE`` keeps every row with the command, date and
machine, and ``--report FILE --update docs/speed.md`` regenerates that file's
``<!-- benchmark PATH -->`` blocks (median and range over the runs) from it:

    python scripts/benchmark.py --runs 5 --out docs/speed/benchmark.json
    python scripts/benchmark.py --report docs/speed/benchmark.json --update docs/speed.md
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import torch
import typer
from mujoco import rollout as mj_rollout
from rich.console import Console
from rich.table import Table

from m3p2i.provenance import machine, versions
from measure.speed_report import update
from planner_client.build import build_controller
from planner_client.problem import apply_planning_model, tune_planning_model
from shared import protocol as P
from shared.config import ConfigError
from shared.scenario import load_scenario
from shared.scene import build_spec, compile_model, get_full_state, initial_data

SCENARIOS = ("navigation", "push_pull", "push_pull_fast", "pick_place")

app = typer.Typer(add_completion=False)


def measure(
    scenario,
    iterations: int,
    nthread: int,
    rounds: int = 20,
    backend: str = "mujoco",
    device: str = "cuda:0",
) -> dict:
    """Median planner iteration and median bare rollouts, measured in alternating blocks.

    The controller runs closed loop (its command applied to its own copy of the world, a state
    per step as a lock-step world publishes it). The bare rollouts
    replay exactly the planner's own work: the [S, T] samples and start states of its last
    iterations, on the world model over the same seconds (no planner sensors), on the planner's
    own model without sensors, and on it with the sensors its costs read. Blocks alternate
    ``rounds`` times (blocks of ten iterations by default), so that background load and a
    virtual machine's drifting speed hit all four alike; each pool is used only in its own block
    so idle threads never compete.
    """
    controller = build_controller(scenario, nthread, backend=backend, device=device)
    planner = controller.motion
    model = planner.problem.model
    data = initial_data(scenario, model)  # the scenario's start pose (the Panda's ready pose)
    world = compile_model(scenario)
    own_spec = build_spec(scenario)
    own_spec.option.timestep = model.opt.timestep
    apply_planning_model(own_spec, scenario.planner.model, scenario.source)
    own = compile_model(scenario, own_spec)
    tune_planning_model(own, scenario.planner.model)
    hold = round(model.opt.timestep / world.opt.timestep)  # world steps per planned step
    samples, horizon = planner.mppi.num_samples, scenario.planner.horizon
    pool_data = [mujoco.MjData(world) for _ in range(nthread)]
    own_data = [mujoco.MjData(own) for _ in range(nthread)]
    work: list[tuple[np.ndarray, np.ndarray]] = []  # (planner x0, samples) of recent iterations
    times: dict[str, list[float]] = {"plan": [], "world": [], "own": [], "sensors": []}
    block = max(1, iterations // rounds)

    def timed(key, fn):
        for i in range(block + 3):
            t = time.perf_counter()
            took = fn()
            if i >= 3:  # the first calls of a block warm caches and threads
                times[key].append(took if took is not None else time.perf_counter() - t)

    controller.begin("lockstep", model.opt.timestep)
    seq = iter(range(10**9))

    def plan_step() -> float:
        """One controller step, timed by itself (the command's ``plan_time``): the world's
        step and the copies kept for the replays around it are the harness's work, not the
        planner's (60 µs of navigation's)."""
        cmd = controller.step(
            P.State(
                session="bench",
                seq=next(seq),
                time=float(data.time),
                qpos=data.qpos.copy(),
                qvel=data.qvel.copy(),
                act=data.act.copy(),
                mocap_pos=data.mocap_pos.copy(),
                mocap_quat=data.mocap_quat.copy(),
            )
        )
        # the start state the iteration rolled out from: the mirror's (no delays: no prediction)
        x0 = get_full_state(model, controller.mirror.data).copy()
        work.append((x0, planner.last_samples.copy()))
        del work[:-block]
        data.ctrl[:] = cmd.ctrl
        mujoco.mj_step(model, data)
        return cmd.plan_time

    counter = iter(range(10**9))

    def world_rollout():
        # sensors add no state, so the planner's x0 is a valid world state
        x0, ctrl = work[next(counter) % len(work)]
        pool.rollout(
            world, pool_data, x0[None], np.repeat(ctrl, hold, axis=1), nstep=horizon * hold
        )

    def own_rollout():
        x0, ctrl = work[next(counter) % len(work)]
        pool.rollout(own, own_data, x0[None], ctrl, nstep=horizon)

    # with planner.model.variants' spread: all, every sample rolls out in every variant
    copies = (
        planner.variants.cfg.count
        if planner.variants is not None and planner.variants.cfg.spread == "all"
        else 1
    )

    def sensor_rollout():
        x0, ctrl = work[next(counter) % len(work)]
        ctrl = np.tile(ctrl, (copies, 1, 1))
        planner.engine.sensors(x0, torch.from_numpy(ctrl).to(planner.device))

    try:
        with mj_rollout.Rollout(nthread=nthread) as pool:
            for _ in range(rounds):
                timed("plan", plan_step)
                timed("world", world_rollout)
                timed("own", own_rollout)
                timed("sensors", sensor_rollout)
    finally:
        controller.close()
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {
        "scenario": scenario.name,
        "samples": samples,
        "horizon": horizon,
        "hz": round(1.0 / med["plan"], 2),
        "planning_step": float(model.opt.timestep),
        "world_step": float(world.opt.timestep),
        "planning_model": scenario.planner.model.as_dict(),
        "ratio_to_rollout": round(med["plan"] / med["world"], 3),
        "ratio_to_own_rollout": round(med["plan"] / med["own"], 3),
        "ratio_to_sensor_rollout": round(med["plan"] / med["sensors"], 3),
        "iteration_ms": round(med["plan"] * 1e3, 3),
        "rollout_ms": round(med["world"] * 1e3, 3),
        "own_rollout_ms": round(med["own"] * 1e3, 3),
        "sensor_rollout_ms": round(med["sensors"] * 1e3, 3),
        "threads": nthread,
        "backend": backend,
        "device": device if backend == "warp" else "cpu",
    }


@app.command()
def main(
    scenario: list[str] = typer.Option(
        list(SCENARIOS), "--scenario", "-s", help="Scenarios to run."
    ),
    iterations: int = typer.Option(200, "--iterations", "-n", help="Timed planner iterations."),
    threads: int = typer.Option(0, help="Rollout threads (0: one per core)."),
    as_json: bool = typer.Option(False, "--json", help="One JSON object per line per case."),
    backend: str = typer.Option(
        "mujoco",
        help="Rollout backend: mujoco (mujoco.rollout on the "
        "CPU) or warp (MuJoCo Warp, the m3p2i\\[gpu] extra).",
    ),
    device: str = typer.Option("cuda:0", help="The warp backend's device: cuda:N or cpu."),
    samples: str = typer.Option(
        "",
        help="Samples per mode, comma-separated (1024,4096,16384): "
        "one case each; default: the scenario's planner.samples.",
    ),
    horizon: int = typer.Option(
        0,
        min=0,
        help="Planned steps instead of the scenario's "
        "planner.horizon (0: the scenario's), each of its "
        "planner.timestep: what a longer or shorter plan would cost.",
    ),
    runs: int = typer.Option(1, min=1, help="Repeat the whole measurement this many times."),
    out: Path | None = typer.Option(
        None, help="Write every row, with the command, date and machine, to this JSON file."
    ),
    report: Path | None = typer.Option(
        None,
        help="Measure nothing: regenerate the "
        "'<!-- benchmark PATH -->' blocks of --update from "
        "the results files they name.",
    ),
    update_file: Path | None = typer.Option(
        None, "--update", help="Markdown file whose benchmark blocks --report regenerates."
    ),
) -> None:
    if report is not None or update_file is not None:
        if update_file is None:
            raise typer.BadParameter("--report needs --update FILE", param_hint="--update")
        update_file.write_text(update(update_file.read_text(), update_file.parent))
        typer.echo(f"updated {update_file}")
        return
    nthread = threads or os.cpu_count() or 1
    try:
        counts = [int(v) for v in samples.split(",") if v.strip()] or [None]
    except ValueError:
        raise typer.BadParameter(
            f"{samples!r}: expected integers separated by commas", param_hint="--samples"
        ) from None
    rows = []
    for run in range(runs):
        for name in scenario:
            for count in counts:
                sc = load_scenario(name)
                if count is not None:
                    sc = dataclasses.replace(
                        sc, planner=dataclasses.replace(sc.planner, samples=count)
                    )
                if horizon:
                    sc = dataclasses.replace(
                        sc, planner=dataclasses.replace(sc.planner, horizon=horizon)
                    )
                try:
                    row = measure(sc, iterations, nthread, backend=backend, device=device)
                except ConfigError as exc:
                    print(f"{name}: skipped: {exc}", flush=True)
                    break
                rows.append({**row, "run": run})
                if as_json:
                    print(json.dumps(row), flush=True)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(
            json.dumps(
                {
                    "command": "python scripts/benchmark.py " + " ".join(sys.argv[1:]),
                    "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                    "machine": machine(),
                    "versions": versions(),
                    "threads": nthread,
                    "iterations": iterations,
                    "runs": runs,
                    "rows": rows,
                },
                indent=1,
            )
        )
        typer.echo(f"results: {out}")
    if not as_json:
        where = (
            f"{backend} backend on {device}" if backend == "warp" else f"{nthread} rollout threads"
        )
        table = Table(title=f"planner speed ({where}, median of {iterations})")
        for col in (
            "scenario",
            "samples x horizon",
            "planner Hz",
            "iteration ms",
            "world rollout ms",
            "ratio",
            "own rollout ms",
            "ratio to it",
            "own + sensors ms",
            "ratio to it",
        ):
            table.add_column(col, justify="right")
        for r in rows:
            table.add_row(
                r["scenario"],
                f"{r['samples']} x {r['horizon']}",
                f"{r['hz']:.1f}",
                f"{r['iteration_ms']:.2f}",
                f"{r['rollout_ms']:.2f}",
                f"{r['ratio_to_rollout']:.2f}",
                f"{r['own_rollout_ms']:.2f}",
                f"{r['ratio_to_own_rollout']:.2f}",
                f"{r['sensor_rollout_ms']:.2f}",
                f"{r['ratio_to_sensor_rollout']:.2f}",
            )
        Console().print(table)


if __name__ == "__main__":
    app()
