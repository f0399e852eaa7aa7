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
machine, and ``--report FILE --update docs/speed.md`` regenerates the ``<!-- benchmark PATH
-->`` blocks of docs/speed.md that name FILE (median and range over the runs); ``--report FILE``
alone prints its tables:

    python scripts/benchmark.py --runs 5 --out docs/speed/benchmark.json
    python scripts/benchmark.py --report docs/speed/benchmark.json --update docs/speed.md
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated

import mujoco
import numpy as np
import torch
import typer
from mujoco import rollout as mj_rollout
from rich.console import Console
from rich.table import Table

from m3p2i.blocks import read_doc, read_results
from m3p2i.cli_support import scenarios_or_exit
from m3p2i.provenance import machine, versions
from measure.speed_report import update
from planner_client.build import build_controller
from planner_client.controller import Controller
from planner_client.maps import map_config
from planner_client.model_state import get_full_state
from planner_client.motion import MotionPlanner
from planner_client.problem import apply_planning_model, planner_scenario, tune_planning_model
from server.sensors import RangeSensors
from shared import protocol as P
from shared.config import ConfigError
from shared.scenario import ROLLOUT_BACKENDS, Scenario, load_scenario
from shared.scene import build_spec, compile_model, initial_data

SCENARIOS = ("navigation", "push_pull", "push_pull_fast", "pick_place", "mobile_pick_place")

app = typer.Typer(add_completion=False)

ROUNDS = 20  # blocks of planner iterations, each followed by blocks of bare rollouts


def _own_model(scenario: Scenario, timestep: float) -> mujoco.MjModel:
    """The planner's own model (its options, with steps of ``timestep``) without the sensors
    its costs read: without the perceived objects, as the planner builds it."""
    own_spec = build_spec(planner_scenario(scenario))
    own_spec.option.timestep = timestep
    apply_planning_model(own_spec, scenario.planner.model, scenario.source)
    own = compile_model(scenario, own_spec)
    tune_planning_model(own, scenario.planner.model)
    return own


def _variant_copies(planner: MotionPlanner) -> int:
    """How many times the planner rolls out each sample: with planner.model.variants' spread:
    all, every sample rolls out in every variant."""
    return (
        planner.variants.cfg.count
        if planner.variants is not None and planner.variants.cfg.spread == "all"
        else 1
    )


@dataclasses.dataclass
class _Sensing:
    """The scenario's range sensors read off the world the controller drives: the world's
    full model (with the objects only the sensors show; they stand still here) posed as the
    planner's copy of the world, so the map is fed as a lock-step world feeds it."""

    world: mujoco.MjModel
    data: mujoco.MjData
    sensors: RangeSensors

    @classmethod
    def of(cls, scenario: Scenario) -> _Sensing | None:
        """None for a scenario without sensors."""
        if not scenario.sensors:
            return None
        world = compile_model(scenario)
        return cls(world, initial_data(scenario, world), RangeSensors(scenario, world))

    def scans(self, data: mujoco.MjData) -> list:
        """The readings due at ``data``'s time (the planner's model: the same joints, as its
        perceived objects are fixed)."""
        self.data.qpos[:], self.data.time = data.qpos, data.time
        mujoco.mj_kinematics(self.world, self.data)
        self.sensors.update(self.world, self.data)
        return self.sensors.take()


def _lockstep_state(data: mujoco.MjData, seq: int) -> P.State:
    """The state of ``data`` as a lock-step world publishes it."""
    return P.State(
        session="bench",
        seq=seq,
        time=float(data.time),
        qpos=data.qpos.copy(),
        qvel=data.qvel.copy(),
        act=data.act.copy(),
        mocap_pos=data.mocap_pos.copy(),
        mocap_quat=data.mocap_quat.copy(),
    )


@dataclasses.dataclass
class _Bench:
    """The controller in closed loop and the bare rollouts that replay its recent iterations,
    each timed in blocks of its own (see :func:`measure`)."""

    controller: Controller
    planner: MotionPlanner
    model: mujoco.MjModel  # the planner's
    data: mujoco.MjData  # the world the controller drives, in the planner's model
    world: mujoco.MjModel
    own: mujoco.MjModel  # the planner's own model without sensors (_own_model)
    hold: int  # world steps per planned step
    horizon: int
    copies: int  # rollouts of each sample (_variant_copies)
    block: int  # timed calls per block
    world_data: list[mujoco.MjData]  # one per rollout thread
    own_data: list[mujoco.MjData]
    sensing: _Sensing | None
    work: list[tuple[np.ndarray, np.ndarray]] = dataclasses.field(default_factory=list)
    times: dict[str, list[float]] = dataclasses.field(
        default_factory=lambda: {"plan": [], "world": [], "own": [], "sensors": []}
    )
    map_times: list[float] = dataclasses.field(default_factory=list)  # s per map update
    seq: Iterator[int] = dataclasses.field(default_factory=itertools.count)
    replayed: Iterator[int] = dataclasses.field(default_factory=itertools.count)

    @classmethod
    def around(cls, scenario: Scenario, controller: Controller, nthread: int, block: int) -> _Bench:
        """The harness of ``controller``, its world at the scenario's start and ``nthread``
        rollout threads, timing ``block`` calls per block."""
        planner = controller.motion
        model = planner.problem.model
        data = initial_data(scenario, model)  # the scenario's start pose (the Panda's ready pose)
        world = compile_model(scenario)
        own = _own_model(scenario, model.opt.timestep)
        return cls(
            controller=controller,
            planner=planner,
            model=model,
            data=data,
            world=world,
            own=own,
            hold=round(model.opt.timestep / world.opt.timestep),
            horizon=scenario.planner.horizon,
            copies=_variant_copies(planner),
            block=block,
            world_data=[mujoco.MjData(world) for _ in range(nthread)],
            own_data=[mujoco.MjData(own) for _ in range(nthread)],
            sensing=_Sensing.of(scenario),
        )

    def run_round(self, pool: mj_rollout.Rollout) -> None:
        """One block of each in turn: planner iterations, then the replays on the world's
        model, on the planner's own, and on it with its sensors."""
        self._timed("plan", self._plan_step)
        self._timed("world", self._world_rollout, pool)
        self._timed("own", self._own_rollout, pool)
        self._timed("sensors", self._sensor_rollout)

    def medians(self) -> dict[str, float]:
        """The median seconds of each kind of call."""
        return {k: float(np.median(v)) for k, v in self.times.items()}

    def _timed(self, key: str, fn: Callable[..., float | None], *args) -> None:
        for i in range(self.block + 3):
            t = time.perf_counter()
            took = fn(*args)
            if i >= 3:  # the first calls of a block warm caches and threads
                self.times[key].append(took if took is not None else time.perf_counter() - t)

    def _plan_step(self) -> float:
        """One controller step, timed by itself (the command's ``plan_time``): the world's
        step and the copies kept for the replays around it are the harness's work, not the
        planner's (60 µs of navigation's). The map is updated before it, timed apart: a
        real-time planner updates it beside its iterations (planner_client/perception)."""
        self._update_map()
        cmd = self.controller.step(_lockstep_state(self.data, next(self.seq)))
        # the start state the iteration rolled out from: the mirror's (no delays: no prediction)
        x0 = get_full_state(self.model, self.controller.mirror.data).copy()
        self.work.append((x0, self.planner.last_samples.copy()))
        del self.work[: -self.block]
        self.data.ctrl[:] = cmd.ctrl
        mujoco.mj_step(self.model, self.data)
        return cmd.plan_time

    def _update_map(self) -> None:
        """Feed the map the scans due now and update it, as a lock-step controller does at a
        state that brings scans; its time goes to ``map_times``."""
        if self.sensing is None or self.controller.map is None:
            return
        scans = self.sensing.scans(self.data)
        if scans:
            self.controller.map.submit(scans, self.data)  # the scene: the self-filter
            t = time.perf_counter()
            self.controller.map.update_now()
            self.map_times.append(time.perf_counter() - t)

    def _world_rollout(self, pool: mj_rollout.Rollout) -> None:
        # sensors add no state, so the planner's x0 is a valid world state
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        pool.rollout(
            self.world,
            self.world_data,
            x0[None],
            np.repeat(ctrl, self.hold, axis=1),
            nstep=self.horizon * self.hold,
        )

    def _own_rollout(self, pool: mj_rollout.Rollout) -> None:
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        pool.rollout(self.own, self.own_data, x0[None], ctrl, nstep=self.horizon)

    def _sensor_rollout(self) -> None:
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        ctrl = np.tile(ctrl, (self.copies, 1, 1))
        self.planner.engine.sensors(x0, torch.from_numpy(ctrl).to(self.planner.device))


def measure(
    scenario: Scenario,
    iterations: int,
    nthread: int,
    rounds: int = ROUNDS,
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
    bench = _Bench.around(scenario, controller, nthread, block=max(1, iterations // rounds))
    controller.begin("lockstep", bench.model.opt.timestep)
    try:
        with mj_rollout.Rollout(nthread=nthread) as pool:
            for i in range(rounds):
                bench.run_round(pool)
                if i == 0:  # the split over warm iterations only, as the medians
                    bench.planner.phases.keep()
    finally:
        controller.close()
    return _row(scenario, bench, nthread, backend, device)


def _row(scenario: Scenario, bench: _Bench, nthread: int, backend: str, device: str) -> dict:
    """One case's result: what ran, the median times and their ratios."""
    med = bench.medians()
    return {
        "scenario": scenario.name,
        "samples": bench.planner.mppi.num_samples,
        "horizon": bench.horizon,
        "hz": round(1.0 / med["plan"], 2),
        "planning_step": float(bench.model.opt.timestep),
        "world_step": float(bench.world.opt.timestep),
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
        "phases_ms": {k: round(v, 4) for k, v in bench.planner.phases.median_ms().items()},
        **_map_figures(scenario, bench),
    }


def _map_figures(scenario: Scenario, bench: _Bench) -> dict:
    """A scenario with sensors: the map's median update (fusing the scans due and its signed
    distance field), the rate it is updated at (the slower of the fastest sensor and
    ``planner.map.rate``) and the share of one core that takes."""
    if not bench.map_times:
        return {}
    update = float(np.median(bench.map_times))
    rate = min(max(s.rate for s in scenario.sensors), map_config(scenario).rate_hz)
    return {
        "map_update_ms": round(update * 1e3, 3),
        "map_rate_hz": rate,
        "map_core_share": round(update * rate, 4),
    }


ScenariosOption = Annotated[list[str], typer.Option("--scenario", "-s", help="Scenarios to run.")]
Iterations = Annotated[
    int,
    typer.Option(
        "--iterations",
        "-n",
        min=ROUNDS,
        help=f"Timed planner iterations, in {ROUNDS} blocks (rounded down to a multiple).",
    ),
]
Threads = Annotated[int, typer.Option(min=0, help="Rollout threads (0: one per core).")]
AsJson = Annotated[bool, typer.Option("--json", help="One JSON object per line per case.")]
Backend = Annotated[
    str,
    typer.Option(
        help="Rollout backend: mujoco (mujoco.rollout on the "
        "CPU) or warp (MuJoCo Warp, the m3p2i\\[gpu] extra).",
    ),
]
Device = Annotated[str, typer.Option(help="The warp backend's device: cuda:N or cpu.")]
Samples = Annotated[
    str,
    typer.Option(
        help="Samples per mode, comma-separated (1024,4096,16384): "
        "one case each; default: the scenario's planner.samples.",
    ),
]
Horizon = Annotated[
    int,
    typer.Option(
        min=0,
        help="Planned steps instead of the scenario's "
        "planner.horizon (0: the scenario's), each of its "
        "planner.timestep: what a longer or shorter plan would cost.",
    ),
]
Runs = Annotated[int, typer.Option(min=1, help="Repeat the whole measurement this many times.")]
Out = Annotated[
    Path | None,
    typer.Option(help="Write every row, with the command, date and machine, to this JSON file."),
]
Report = Annotated[
    Path | None,
    typer.Option(
        help="Measure nothing: regenerate the "
        "'<!-- benchmark PATH -->' blocks of --update that name this results file "
        "(without --update: print its tables).",
    ),
]
UpdateFile = Annotated[
    Path | None,
    typer.Option(
        "--update",
        help="Markdown file whose benchmark blocks are regenerated from the results files "
        "they name (with --report: only the blocks naming it).",
    ),
]


@dataclasses.dataclass(frozen=True)
class Options:
    """What one command measures: every scenario at every sample count, ``runs`` times over,
    and how (the rollout backend and threads, the iterations timed, the output)."""

    scenarios: list[str]
    counts: list[int | None]  # samples per mode, a case each (None: the scenario's)
    horizon: int  # planned steps (0: the scenario's)
    iterations: int
    runs: int
    nthread: int
    backend: str
    device: str
    as_json: bool  # a JSON line per row as it is measured, instead of the table at the end


@app.command()
def main(
    scenario: ScenariosOption = SCENARIOS,
    iterations: Iterations = 200,
    threads: Threads = 0,
    as_json: AsJson = False,
    backend: Backend = "mujoco",
    device: Device = "cuda:0",
    samples: Samples = "",
    horizon: Horizon = 0,
    runs: Runs = 1,
    out: Out = None,
    report: Report = None,
    update_file: UpdateFile = None,
) -> None:
    if report is not None or update_file is not None:
        _regenerate_or_show(report, update_file)
        return
    if backend not in ROLLOUT_BACKENDS:
        raise typer.BadParameter(
            f"{backend!r}: expected one of {', '.join(ROLLOUT_BACKENDS)}", param_hint="--backend"
        )
    counts = _sample_counts(samples)  # before the scenarios: it is the cheaper check
    scenarios_or_exit(scenario)  # every one sound before the first is measured
    opts = Options(
        scenarios=scenario,
        counts=counts,
        horizon=horizon,
        iterations=iterations // ROUNDS * ROUNDS,
        runs=runs,
        nthread=threads or os.cpu_count() or 1,
        backend=backend,
        device=device,
        as_json=as_json,
    )
    rows = []
    for run in range(opts.runs):
        for name in opts.scenarios:
            rows += _measure_cases(name, run, opts)
    if out is not None:
        _save(out, rows, opts)
    if not as_json:
        where = (
            f"{opts.backend} backend on {opts.device}"
            if opts.backend == "warp"
            else f"{opts.nthread} rollout threads"
        )
        _print_table(rows, f"planner speed ({where}, median of {opts.iterations})")


def _regenerate_or_show(report: Path | None, update_file: Path | None) -> None:
    """No run: --update's benchmark blocks regenerated (with --report, those that name it),
    or without --update, --report's tables printed."""
    if update_file is None:
        results = read_results(report, "--report")
        if not isinstance(results, dict) or not isinstance(results.get("rows"), list):
            raise typer.BadParameter(
                f"{report}: no 'rows' (expected a file written by --out)", param_hint="--report"
            )
        _print_table(results["rows"], f"{report}: {results.get('command', '')}")
        return
    text = read_doc(update_file)
    update_file.write_text(update(text, update_file.parent, report), encoding="utf-8")
    typer.echo(f"updated {update_file}")


def _sample_counts(samples: str) -> list[int | None]:
    """--samples' values, or ``[None]`` (the scenario's planner.samples) when empty."""
    try:
        counts = [int(v) for v in samples.split(",") if v.strip()]
    except ValueError:
        counts = [0]
    if any(c < 1 for c in counts):
        raise typer.BadParameter(
            f"{samples!r}: expected integers >= 1 separated by commas", param_hint="--samples"
        )
    return counts or [None]


def _case(name: str, count: int | None, horizon: int) -> Scenario:
    """Scenario ``name`` with ``count`` samples per mode and ``horizon`` planned steps, where
    given."""
    sc = load_scenario(name)
    if count is not None:
        sc = dataclasses.replace(sc, planner=dataclasses.replace(sc.planner, samples=count))
    if horizon:
        sc = dataclasses.replace(sc, planner=dataclasses.replace(sc.planner, horizon=horizon))
    return sc


def _measure_cases(name: str, run: int, opts: Options) -> list[dict]:
    """Scenario ``name``'s rows of run ``run``, one per sample count; none after the first
    count its configuration refuses (skipped, with a line saying why)."""
    rows = []
    for count in opts.counts:
        sc = _case(name, count, opts.horizon)
        try:
            row = measure(
                sc, opts.iterations, opts.nthread, backend=opts.backend, device=opts.device
            )
        except ConfigError as exc:
            print(f"{name}: skipped: {exc}", flush=True)
            break
        rows.append({**row, "run": run})
        if opts.as_json:
            print(json.dumps(row), flush=True)
    return rows


def _save(out: Path, rows: list[dict], opts: Options) -> None:
    """--out: every row, with the command, date, machine and versions that produced it."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "command": "python scripts/benchmark.py " + " ".join(sys.argv[1:]),
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": machine(),
                "versions": versions(),
                "threads": opts.nthread,
                "iterations": opts.iterations,
                "runs": opts.runs,
                "rows": rows,
            },
            indent=1,
        )
    )
    typer.echo(f"results: {out}")


def _print_table(rows: list[dict], title: str) -> None:
    """The rows as tables on the terminal: the speeds, then the split by phase."""
    table = Table(title=title)
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
    split = Table(title="where an iteration's time goes (median ms per phase)")
    phases = list(dict.fromkeys(p for r in rows for p in r.get("phases_ms", {})))
    for col in ("scenario", *phases):
        split.add_column(col, justify="right")
    for r in rows:
        split.add_row(r["scenario"], *(f"{r['phases_ms'].get(p, 0.0):.3f}" for p in phases))
    Console().print(split)


if __name__ == "__main__":
    app()
