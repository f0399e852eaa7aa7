"""``m3p2i``: the umbrella command. ``m3p2i run SCENARIO`` starts server and planner as two
processes (exactly what two terminals would run), waits for the episode and reports it.

It launches ``python -m server`` and ``python -m planner_client``: the two sides still meet only
over the wire.
"""

from __future__ import annotations

import socket as pysocket
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

import typer

from shared.cli_common import default_run_dir, summary_line
from shared.config import ConfigError
from shared.endpoints import DEFAULT_HOST
from shared.scenario import SCENARIO_DIR, load_scenario

app = typer.Typer(add_completion=False, no_args_is_help=True, help=(
    "m3p2i: reactive task and motion planning with active inference and multi-modal MPPI.\n\n"
    "`m3p2i run navigation` runs a scenario end to end; `m3p2i list` shows the scenarios. "
    "For two terminals use `m3p2i-server` and `m3p2i-planner` directly."))


def free_port_block(host: str = DEFAULT_HOST, count: int = 4) -> int:
    """A base port with ``count`` consecutive free ports on ``host``."""
    for _ in range(50):
        with pysocket.socket() as s:
            s.bind((host, 0))
            base = s.getsockname()[1]
        if base + count >= 65535:
            continue
        ok = True
        for p in range(base, base + count):
            with pysocket.socket() as s:
                try:
                    s.bind((host, p))
                except OSError:
                    ok = False
                    break
        if ok:
            return base
    raise RuntimeError("no block of free ports found")


def read_summary(log_path: Path) -> dict | None:
    import json
    if not log_path.is_file():
        return None
    for line in reversed(log_path.read_text().splitlines()):
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if rec.get("kind") == "summary":
            return rec
    return None


@app.command("run")
def run(
    scenario: str = typer.Argument(..., help="Scenario name (configs/scenarios/NAME.yaml) or path."),
    mode: str = typer.Option("lockstep", help="lockstep (deterministic) or realtime."),
    port: int = typer.Option(0, help="Base port (0: pick free ports)."),
    run_dir: Optional[Path] = typer.Option(None, help="Where logs go (default runs/<scenario>-<time>)."),
    timeout: float = typer.Option(900.0, help="Wall-clock seconds before the run is abandoned."),
    viewer: bool = typer.Option(False, help="Open the MuJoCo viewer on the server."),
    seed: int = typer.Option(0, help="Seed of the randomised start and of the planner's sampling."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Show both processes' output."),
) -> None:
    """Run one episode of SCENARIO with server and planner; exit 0 on success."""
    try:
        sc = load_scenario(scenario)
    except ConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2)
    run_dir = run_dir or default_run_dir(sc.name)
    run_dir.mkdir(parents=True, exist_ok=True)
    port = port or free_port_block()
    log_path = run_dir / "episode.jsonl"
    common = ["--scenario", sc.source, "--port", str(port), "--seed", str(seed)]
    server_cmd = [sys.executable, "-m", "server", *common, "--mode", mode, "--log", str(log_path)]
    planner_cmd = [sys.executable, "-m", "planner_client", *common]
    if viewer:
        server_cmd.append("--viewer")
    typer.echo(f"running {sc.name} ({mode}); logs in {run_dir}")
    outs = {}
    procs = {}
    started = time.monotonic()
    try:
        for name, cmd in (("server", server_cmd), ("planner", planner_cmd)):
            out = None if verbose else (run_dir / f"{name}.log").open("w")
            outs[name] = out
            procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if out else None)
        while procs["server"].poll() is None:
            if time.monotonic() - started > timeout:
                typer.echo(f"error: no outcome within {timeout:.0f} s; stopping", err=True)
                break
            if procs["planner"].poll() not in (None, 0, 1):
                typer.echo(f"error: the planner exited with code {procs['planner'].returncode}; "
                           f"see {run_dir / 'planner.log'}", err=True)
                break
            time.sleep(0.1)
    except KeyboardInterrupt:
        typer.echo("interrupted")
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.terminate()
        for p in procs.values():
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        for out in outs.values():
            if out is not None:
                out.close()
    summary = read_summary(log_path)
    if summary is None:
        typer.echo(f"error: no episode summary in {log_path}", err=True)
        raise typer.Exit(1)
    measures = dict(summary.get("measures", {}), planner_hz=summary.get("planner_hz", 0.0))
    typer.echo(f"{sc.name}: " + summary_line(summary["status"], summary["time"], measures))
    raise typer.Exit(0 if summary["status"] == "success" else 1)


@app.command("list")
def list_scenarios() -> None:
    """List the scenarios shipped in configs/scenarios."""
    for path in sorted(SCENARIO_DIR.glob("*.yaml")):
        try:
            sc = load_scenario(path)
            typer.echo(f"{sc.name:24s} {sc.description}")
        except ConfigError as exc:
            typer.echo(f"{path.stem:24s} (invalid: {exc})")


if __name__ == "__main__":
    app()
