"""Soak and fault test: real-time episodes back to back while faults are injected, then checks
(what is injected and checked: :mod:`scripts.measure.soak`, which this command runs).

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

import typer

from measure.netns import Unavailable, unavailable
from measure.soak import Soak, SoakConfig, print_table, update

app = typer.Typer(add_completion=False)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@app.command()
def main(
    duration: float = typer.Option(
        600.0,
        help="Seconds of episodes and faults (the run ends "
        "at most a minute later, letting the last episode finish).",
    ),
    seed: int = typer.Option(
        0,
        help="Seed of the fault schedule (moments, order, pauses, "
        "garbage) and of the worlds' and planners' seeds.",
    ),
    scenario: str = typer.Option("navigation", help="Scenario name or YAML path."),
    command_timeout: float = typer.Option(0.5, help="The world's --command-timeout (s)."),
    takeover: float = typer.Option(
        3.0,
        help="Bound (s) to the first step driven by a new "
        "command: from a planner's SIGKILL (its hot spare is told to "
        "go at once), a SIGCONT, a new world's start, a flood's end.",
    ),
    rss_bound: float = typer.Option(
        50.0,
        help="Allowed resident-memory growth per process "
        "(MiB), from 5 s (a planner) or 1 s (a world) after it first "
        "drove the robot, or was driven, to its end.",
    ),
    gap_min: float = typer.Option(4.0, help="Least seconds between two faults."),
    gap_max: float = typer.Option(10.0, help="Most seconds between two faults."),
    netns: bool = typer.Option(
        False,
        "--netns",
        help="Two hosts on one machine: the worlds in one network "
        "namespace, the planners in another, joined by a veth pair made for the run and "
        "removed at its end; CURVE on (keys made into OUT/keys). Adds the `cut` fault (the "
        "link down for --cut s mid-episode). Needs root and iproute2's `ip` (else exit 2).",
    ),
    cut: float = typer.Option(2.0, help="Seconds the link is down in a `cut` (--netns)."),
    faults: str | None = typer.Option(
        None,
        help="Comma-separated fault kinds to inject, of kill, restart, flood, pause and cut "
        "(default: all; cut only with --netns).",
    ),
    out: Path | None = typer.Option(
        None, help="Folder for the episode logs and process outputs (default runs/soak-<time>)."
    ),
    results: Path | None = typer.Option(None, help="Results JSON (default OUT/soak.json)."),
    report: Path | None = typer.Option(
        None, help="Only print the table of this results file (no run)."
    ),
    update_file: Path | None = typer.Option(
        None,
        "--update",
        help="Regenerate the "
        "'<!-- soak PATH -->' blocks of this Markdown "
        "file from their results files (no run).",
    ),
) -> None:
    """Run real-time episodes back to back under injected faults (planner SIGKILL and
    replacement, world restart, command-socket garbage, planner SIGSTOP past the command
    time-out) and check that the robot was never driven by a stale command, replacements took
    over in time, the world never died, every log is complete, and memory stayed bounded.
    Exit status 0 only when every check holds; 2 for bad options.

    Example: nice -n 10 python scripts/soak.py --duration 600 --results docs/soak/soak-600s.json;
    then python scripts/soak.py --report docs/soak/soak-600s.json --update docs/reliability.md"""
    if report is not None or update_file is not None:
        if update_file is not None:
            update_file.write_text(update(update_file.read_text(), update_file.parent))
            typer.echo(f"updated {update_file}")
        if report is not None:
            print_table(json.loads(report.read_text()))
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
        faults=None if faults is None else tuple(k.strip() for k in faults.split(",") if k.strip()),
    )
    cfg.check()
    if netns:
        reason = unavailable()
        if reason:
            typer.echo(f"--netns: {reason}", err=True)
            raise typer.Exit(2)
        # a SIGTERM ends the run as Ctrl-C does: processes stopped, namespaces removed
        signal.signal(signal.SIGTERM, _interrupt)
    out = out or Path("runs") / f"soak-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        res = Soak(cfg, out).run()
    except Unavailable as exc:
        typer.echo(f"--netns: {exc}", err=True)
        raise typer.Exit(2) from None
    path = results or out / "soak.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=1) + "\n")
    print_table(res)
    typer.echo(f"results: {path}; logs: {out}")
    raise typer.Exit(0 if res["ok"] else 1)


if __name__ == "__main__":
    app()
