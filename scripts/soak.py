"""Soak and fault test: real-time episodes back to back while faults are injected, then checks
(what is injected and checked: :mod:`scripts.measure.soak_episodes`, which this command runs).

    nice -n 10 python scripts/soak.py --duration 600 --results docs/soak/soak-600s.json
    python scripts/soak.py --report docs/soak/soak-600s.json --update docs/reliability.md

Loopback, or with --netns two network namespaces joined by a veth pair; bounded in time
(duration + a minute at most) and in faults and episodes.
"""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path
from typing import Annotated

import typer

from m3p2i.blocks import read_doc, read_results
from m3p2i.cli_support import scenarios_or_exit
from measure.netns import Unavailable, unavailable
from measure.soak_episodes import Soak, SoakConfig, print_table, update

app = typer.Typer(add_completion=False)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


Duration = Annotated[
    float,
    typer.Option(
        help="Seconds of episodes and faults (the run ends "
        "at most a minute later, letting the last episode finish).",
    ),
]
Seed = Annotated[
    int,
    typer.Option(
        min=0,
        help="Seed of the fault schedule (moments, order, pauses, garbage); the i-th planner "
        "samples with SEED + i, the i-th world starts from seed i.",
    ),
]
ScenarioName = Annotated[str, typer.Option(help="Scenario name or YAML path.")]
CommandTimeout = Annotated[float, typer.Option(help="The world's --command-timeout (s).")]
Takeover = Annotated[
    float,
    typer.Option(
        help="Bound (s) to the first step driven by a new "
        "command: from a planner's SIGKILL (its hot spare is told to "
        "go at once), a SIGCONT, a new world's start, a flood's end.",
    ),
]
RssBound = Annotated[
    float,
    typer.Option(
        help="Allowed resident-memory growth per process "
        "(MiB), from 5 s (a planner) or 1 s (a world) after it first "
        "drove the robot, or was driven, to its end.",
    ),
]
GapMin = Annotated[float, typer.Option(help="Least seconds between two faults.")]
GapMax = Annotated[float, typer.Option(help="Most seconds between two faults.")]
NetNs = Annotated[
    bool,
    typer.Option(
        "--netns",
        help="Two hosts on one machine: the worlds in one network "
        "namespace, the planners in another, joined by a veth pair made for the run and "
        "removed at its end; CURVE on (keys made into OUT/keys). Adds the `cut` fault (the "
        "link down for --cut s mid-episode). Needs root and iproute2's `ip` (else exit 2).",
    ),
]
Cut = Annotated[float, typer.Option(help="Seconds the link is down in a `cut` (--netns).")]
FaultKinds = Annotated[
    str | None,
    typer.Option(
        help="Comma-separated fault kinds to inject, of kill, restart, flood, pause and cut "
        "(default: all; cut only with --netns).",
    ),
]
Out = Annotated[
    Path | None,
    typer.Option(
        help="Folder for the episode logs and process outputs (default runs/soak-<time>)."
    ),
]
Results = Annotated[Path | None, typer.Option(help="Results JSON (default OUT/soak.json).")]
Report = Annotated[
    Path | None, typer.Option(help="Only print the table of this results file (no run).")
]
UpdateFile = Annotated[
    Path | None,
    typer.Option(
        "--update",
        help="Regenerate the "
        "'<!-- soak PATH -->' blocks of this Markdown "
        "file from their results files (no run).",
    ),
]


@app.command()
def main(
    duration: Duration = 600.0,
    seed: Seed = 0,
    scenario: ScenarioName = "navigation",
    command_timeout: CommandTimeout = 0.5,
    takeover: Takeover = 3.0,
    rss_bound: RssBound = 50.0,
    gap_min: GapMin = 4.0,
    gap_max: GapMax = 10.0,
    netns: NetNs = False,
    cut: Cut = 2.0,
    faults: FaultKinds = None,
    out: Out = None,
    results: Results = None,
    report: Report = None,
    update_file: UpdateFile = None,
) -> None:
    """Run real-time episodes back to back under injected faults (planner SIGKILL and
    replacement, world restart, command-socket garbage, planner SIGSTOP past the command
    time-out) and check that the robot was never driven by a stale command, replacements took
    over in time, the world never died, every log is complete, and memory stayed bounded.
    Exit status 0 only when every check holds; 2 for bad options.

    Example: nice -n 10 python scripts/soak.py --duration 600 --results docs/soak/soak-600s.json;
    then python scripts/soak.py --report docs/soak/soak-600s.json --update docs/reliability.md"""
    if report is not None or update_file is not None:
        _regenerate_or_show(report, update_file)
        return
    cfg = SoakConfig(
        duration=duration,
        seed=seed,
        scenario=scenario,
        command_timeout=command_timeout,
        takeover=takeover,
        rss_bound=rss_bound,
        gap=(gap_min, gap_max),
        netns=netns,
        cut_s=cut,
        faults=_fault_kinds(faults),
    )
    cfg.check()  # before the scenario, whose checks start both processes
    scenarios_or_exit([scenario], teams=False)
    if netns:
        _prepare_netns()
    out = out or Path("runs") / f"soak-{time.strftime('%Y%m%d-%H%M%S')}"
    res = _run_or_exit(cfg, out)
    path = results or out / "soak.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=1) + "\n")
    print_table(res)
    typer.echo(f"results: {path}; logs: {out}")
    raise typer.Exit(0 if res["ok"] else 1)


def _regenerate_or_show(report: Path | None, update_file: Path | None) -> None:
    """No run: --update's soak blocks regenerated, then --report's table printed."""
    if update_file is not None:
        text = read_doc(update_file)
        update_file.write_text(update(text, update_file.parent), encoding="utf-8")
        typer.echo(f"updated {update_file}")
    if report is not None:
        print_table(read_results(report, "--report"))


def _fault_kinds(faults: str | None) -> tuple[str, ...] | None:
    """--faults' kinds (None: every kind that applies)."""
    return None if faults is None else tuple(k.strip() for k in faults.split(",") if k.strip())


def _prepare_netns() -> None:
    """Exit 2 where network namespaces cannot be made; else let SIGTERM end the run as
    Ctrl-C does: processes stopped, namespaces removed."""
    reason = unavailable()
    if reason:
        typer.echo(f"--netns: {reason}", err=True)
        raise typer.Exit(2)
    signal.signal(signal.SIGTERM, _interrupt)


def _run_or_exit(cfg: SoakConfig, out: Path) -> dict:
    """The soak's results, its logs in ``out``; exit 2 when its namespaces fail."""
    try:
        return Soak(cfg, out).run()
    except Unavailable as exc:
        typer.echo(f"--netns: {exc}", err=True)
        raise typer.Exit(2) from None


if __name__ == "__main__":
    app()
