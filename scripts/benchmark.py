"""Planner speed: iterations per second, and the ratio of one iteration to a bare rollout.

For each scenario the planner's control loop (:class:`planner_client.controller.Controller`, as
the planner process runs it) runs closed loop in-process, its command applied to a copy of the
world, and each iteration (mirror -> task layer -> sample -> mujoco.rollout -> costs -> M3P2I
update -> command: the planning time a world logs) is timed against bare ``mujoco.rollout`` calls
replaying the planner's own samples and start states (same thread count, persistent pool;
the harness: :mod:`scripts.measure.planner_speed`):

- ``ratio_to_rollout``: to the world model over the same horizon in seconds (each control held
  for ``planner.timestep / world.timestep`` world steps): what planning costs against simulating
  the world itself. Below 1 when the planner's own model (``planner.model``, ``planner.timestep``)
  is cheaper than the world's.
- ``ratio_to_own_rollout``: to the planner's own model (its options and timestep) without the
  sensors its costs read: what an iteration adds to its own bare rollout.
- ``ratio_to_sensor_rollout``: to the planner's own model with those sensors: the difference to
  the previous one is what the sensors cost.

Each row also splits the median iteration by phase (``phases_ms``), and splits once more
iterations whose rollout returns a copy of a real one's result (``phases_replayed_ms``, run after
the others): the rest of an iteration without a rollout evicting its code and data from the
caches, its floor however fast the rollout.

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
import json
import os
import sys
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from m3p2i.blocks import read_doc, read_results
from m3p2i.cli_support import scenarios_or_exit
from m3p2i.provenance import machine, versions
from measure.speed_report import rest_ms, update
from shared.config import ConfigError
from shared.scenario import ROLLOUT_BACKENDS, Scenario, load_scenario

SCENARIOS = ("navigation", "push_pull", "push_pull_fast", "pick_place", "mobile_pick_place")

app = typer.Typer(add_completion=False)

ROUNDS = 20  # blocks of planner iterations, each followed by blocks of bare rollouts


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
    # torch and the planner load here, once every option has been checked: a wrong option is
    # answered in a fraction of a second
    from measure.planner_speed import measure

    rows = []
    for count in opts.counts:
        sc = _case(name, count, opts.horizon)
        try:
            row = measure(sc, opts.iterations, opts.nthread, ROUNDS, opts.backend, opts.device)
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
    """The rows as tables on the terminal: the speeds, the split by phase, and the rest of an
    iteration as measured and with its rollout replayed."""
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
    replayed = [r for r in rows if "phases_replayed_ms" in r]  # none in older results files
    if not replayed:
        return
    rest = Table(title="all but the rollout (ms), as measured and with the rollout replayed")
    for col in ("scenario", "as measured", "rollout replayed"):
        rest.add_column(col, justify="right")
    for r in replayed:
        measured, floor = rest_ms(r["phases_ms"]), rest_ms(r["phases_replayed_ms"])
        rest.add_row(r["scenario"], f"{measured:.3f}", f"{floor:.3f}")
    Console().print(rest)


if __name__ == "__main__":
    app()
