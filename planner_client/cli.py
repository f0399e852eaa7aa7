"""``m3p2i-planner``: the planner process."""

from __future__ import annotations

import dataclasses
import logging
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from planner_client.keys import load_planner_keys
from planner_client.options import MeasureDelays, OldMeasureDelays, Plugins
from planner_client.signals import signals_as_ctrl_c
from shared.cli_common import (
    Host,
    Insecure,
    Keys,
    ParentPid,
    Port,
    ScenarioOption,
    Verbose,
    collector_back,
    keys_or_exit,
    print_errors,
    renamed,
    setup_logging,
    stop_with_parent,
)
from shared.config import ConfigError, ConfigErrors
from shared.endpoints import DEFAULT_HOST, DEFAULT_PORT, Endpoints
from shared.protocol import MAX_SEED
from shared.scenario import Scenario, load_scenario

app = typer.Typer(add_completion=False)

HELP = (
    "Run the planner: mirror the world server's state into batched MuJoCo rollouts, choose the "
    "task's modes (fixed, or by active inference), run M3P2I and send commands back.\n\n"
    "Start `m3p2i-server` with the same scenario first (either order works: the planner waits). "
    "Across machines give both sides `--keys DIR` (made by `m3p2i keys DIR`): ZeroMQ CURVE, "
    "authenticated and encrypted. "
    "Exit code: 0 when the episode ends in success, 1 otherwise, 2 on a configuration error, "
    "3 when the server refuses the handshake (scenario, protocol version or key) or its first "
    "state has other sizes than the scenario's model (`m3p2i layout SCENARIO` prints them), "
    "4 when the planner itself fails (an uncaught error, e.g. a cost term that raises: its "
    "traceback is printed)."
)

log = logging.getLogger("m3p2i.planner")


DiagnosticsHost = Annotated[
    str,
    typer.Option(
        help="Address on this machine to bind the diagnostics (port+3) to; a network address "
        "needs --keys, or --insecure."
    ),
]
Threads = Annotated[
    int,
    typer.Option(
        min=0, help="Rollout threads (0: the scenario's planner.threads, else one per core)."
    ),
]
ServerTimeout = Annotated[
    float, typer.Option(min=0.001, help="Seconds of silence before reconnecting.")
]
KeepRunning = Annotated[
    bool,
    typer.Option(help="Keep planning across episodes instead of exiting when the episode ends."),
]
SamplingSeed = Annotated[
    int | None,
    typer.Option(
        min=0, max=MAX_SEED, help="Sampling seed (default: planner.mppi.seed of the scenario)."
    ),
]
Backend = Annotated[
    str | None,
    typer.Option(
        help="Rollout backend, overriding the scenario's planner.backend: 'mujoco' "
        "(mujoco.rollout's thread pool on the CPU, the default) or 'warp' (MuJoCo Warp, from the "
        "m3p2i\\[gpu] extra: thousands of samples on a GPU; it compiles its kernels on first use, "
        "cached in ~/.cache/warp)."
    ),
]
Device = Annotated[
    str | None,
    typer.Option(
        help="The warp backend's device, overriding planner.device: cuda:0 (default), cuda:N, "
        "or cpu (slow, for tests without a GPU)."
    ),
]
CheckOnly = Annotated[
    bool,
    typer.Option(
        "--check",
        help="Only check the scenario (every error of the file, cost terms and model names "
        "included) and exit: 0 sound, 2 faulty.",
    ),
]
Standby = Annotated[
    bool,
    typer.Option(
        help="Hot spare for a supervisor: load the scenario and compile the models, print "
        "'standby: ready', then wait for a line on standard input before connecting (end of "
        "input: exit 1 unconnected). It then takes over in a fraction of a second instead of a "
        "cold start's several."
    ),
]
ActuationDelay = Annotated[
    float | None,
    typer.Option(
        min=0.0,
        help="Declared actuation delay of the robot (ms from a command reaching the world to "
        "the actuators acting on it), overriding planner.delays.actuation_ms: the planner plans "
        "from the state predicted for when its plan acts (docs/faults.md).",
    ),
]
StateDelay = Annotated[
    float | None,
    typer.Option(
        min=0.0,
        help="Declared state delay (ms from a measurement to its state being published), "
        "overriding planner.delays.state_ms.",
    ),
]
MaxRate = Annotated[
    float,
    typer.Option(
        min=0.0,
        help="At most this many plans per second (0: as fast as the machine allows): rehearse "
        "what a slower computer does, e.g. a planner under a third of a 100 Hz arm's rate with "
        "--max-rate 25 (in real time; lock-step has m3p2i-server --plan-every).",
    ),
]


RobotOption = Annotated[
    str | None,
    typer.Option(
        "--robot",
        help="In a scenario of several robots (robots:), the one this planner drives: it plans "
        "that robot's controls, the others rolled out along their planners' plans "
        "(docs/teams.md). Start one planner per robot.",
    ),
]


def member_of(scenario: Scenario, robot: str | None) -> Scenario:
    """The scenario as ``robot``'s planner reads it; a ConfigError when ``robot`` is not one
    of its team (or a team's scenario got no robot, or one robot's scenario got one)."""
    names = list(scenario.members)
    if robot is None and not names:
        return scenario
    if robot is None or robot not in names:
        expected = f"--robot with one of: {', '.join(names)}" if names else "no --robot"
        what = "has one robot" if not names else "drives several robots"
        raise ConfigError(scenario.source, "robots", f"this scenario {what}", robot, expected)
    return scenario.members[robot]


@app.command(help=HELP)
def main(
    scenario: ScenarioOption,
    host: Host = DEFAULT_HOST,
    port: Port = DEFAULT_PORT,
    diagnostics_host: DiagnosticsHost = DEFAULT_HOST,
    keys: Keys = None,
    insecure: Insecure = False,
    threads: Threads = 0,
    server_timeout: ServerTimeout = 2.0,
    keep_running: KeepRunning = False,
    seed: SamplingSeed = None,
    backend: Backend = None,
    device: Device = None,
    check: CheckOnly = False,
    standby: Standby = False,
    actuation_delay_ms: ActuationDelay = None,
    state_delay_ms: StateDelay = None,
    measure_delays: MeasureDelays = False,
    plugins: Plugins = None,
    max_rate: MaxRate = 0.0,
    robot: RobotOption = None,
    verbose: Verbose = False,
    parent_pid: ParentPid = None,
    estimate_delays: OldMeasureDelays = False,
) -> None:
    setup_logging(verbose, "m3p2i.planner")
    measure_delays = renamed(
        measure_delays, estimate_delays, "--measure-delays", "--estimate-delays", False
    )
    # before anything else: an exposed robot is refused at once (--check checks no keys)
    planner_keys = (
        None
        if check
        else keys_or_exit(
            {"--host": host, "--diagnostics-host": diagnostics_host},
            keys,
            insecure,
            load_planner_keys,
            log.warning,
        )
    )
    from planner_client.build import build_client
    from planner_client.mujoco_warnings import count_mujoco_warnings
    from planner_client.phases import STARTUP

    STARTUP.mark("imports")
    _checked_or_exit(scenario, plugins, check)
    device = _rollouts_or_exit(backend, device)
    STARTUP.mark("check")
    warned = count_mujoco_warnings()  # each said once in the log, then counted

    try:
        sc = with_delays(
            member_of(load_scenario(scenario), robot),
            actuation_delay_ms,
            state_delay_ms,
            measure_delays,
        )
        client = build_client(
            sc,
            Endpoints(host, port),
            threads=threads,
            seed=seed,
            backend=backend,
            device=device,
            server_timeout=server_timeout,
            exit_on_done=not keep_running,
            keys=planner_keys,
            diagnostics_host=diagnostics_host,
            max_rate=max_rate,
            before_connect=_await_go if standby else None,
        )
    except ConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    except Exception as exc:
        _failed(exc, "building the planner")
    STARTUP.mark("build")
    collector_back()
    _plan(client, scenario, warned, parent_pid)


def _checked_or_exit(scenario: str, plugins: list[str] | None, check: bool) -> None:
    """The operator's ``--plugins`` imported and the scenario checked (cost terms and model
    names included): every error printed and exit 2; with ``--check``, exit 0 when sound."""
    from planner_client.planner_check import scenario_errors
    from planner_client.plugins import import_plugins

    try:  # the operator's own modules, before the scenario's terms are looked up
        import_plugins(plugins or [], Path.cwd(), "m3p2i-planner", "--plugins")
    except ConfigError as exc:
        print_errors(exc.errors if isinstance(exc, ConfigErrors) else [exc], err=not check)
        raise typer.Exit(2) from None
    errors = scenario_errors(scenario)  # every error of the file, before anything starts
    print_errors(errors, err=not check)
    if errors or check:
        raise typer.Exit(2 if errors else 0)


def _rollouts_or_exit(backend: str | None, device: str | None) -> str | None:
    """``--backend`` among the rollout backends and ``--device`` a device they know (returned
    as read); exit 2 otherwise."""
    from shared.scenario import ROLLOUT_BACKENDS, rollout_device

    if backend is not None and backend not in ROLLOUT_BACKENDS:
        typer.echo(
            f"error: --backend {backend!r}: expected one of {', '.join(ROLLOUT_BACKENDS)}", err=True
        )
        raise typer.Exit(2)
    try:
        return device if device is None else rollout_device(device)
    except ValueError as exc:
        typer.echo(f"error: --device {device!r}: {exc}", err=True)
        raise typer.Exit(2) from None


def _plan(client, scenario: str, warned, parent_pid: int | None) -> None:
    """Plan until the episode (or, kept running, the world) ends, or launcher ``parent_pid``
    is gone; print the planner's statistics and exit 0 on success, 1 otherwise, 3 when the
    world refuses this planner, 4 when planning fails."""
    from planner_client.controller import LayoutMismatch
    from planner_client.loop import HandshakeRefused

    stop_with_parent(parent_pid)
    with signals_as_ctrl_c():  # a supervisor's SIGTERM, too, ends in the statistics
        try:
            stats = client.run()
        except HandshakeRefused as exc:
            typer.echo(f"error: the server refused the handshake: {exc}", err=True)
            raise typer.Exit(3) from None
        except LayoutMismatch as exc:
            typer.echo(f"error: {exc.explain(scenario)}", err=True)
            raise typer.Exit(3) from None
        except KeyboardInterrupt:
            stats = client.stats
        except Exception as exc:
            _failed(exc, "planning")
        finally:
            client.close()
    fallbacks = (
        f", {stats.safe_fallbacks} safe controls for want of a finite plan"
        if stats.safe_fallbacks
        else ""
    )
    dropped = (
        f", {client.dropped_states} bad state messages dropped" if client.dropped_states else ""
    )
    mujoco = f", {warned.total} MuJoCo warnings" if warned.total else ""
    m = stats.map
    mapped = (
        f", map: {m['fields']:.0f} fields, {m['rate_hz']:.1f} Hz, {m['update_s'] * 1e3:.1f} ms each"
        if m
        else ""
    )
    budget = "".join(
        f", {label} changed {len(shed)} times (fewest {min(c[3] for c in shed)})"
        for what, label in (("samples", "samples per mode"), ("horizon", "horizon steps"))
        if (shed := [c for c in stats.budget_changes if c[1] == what])
    )
    typer.echo(
        f"planner: {stats.iterations} iterations, {stats.hz:.1f} Hz, "
        f"episode {stats.final_status or 'not finished'}{fallbacks}{dropped}{mujoco}{mapped}"
        f"{budget}"
    )
    raise typer.Exit(0 if stats.final_status == "success" else 1)


def _failed(exc: Exception, during: str) -> NoReturn:
    """An uncaught error (a bug, or a user's cost term that raises): its traceback, one
    ``error:`` line, and exit 4, which a launcher tells apart from an episode's end (0, 1)."""
    log.error("the planner failed while %s", during, exc_info=exc)
    typer.echo(f"error: the planner failed: {type(exc).__name__}: {exc}", err=True)
    raise typer.Exit(4) from None


def with_delays(sc, actuation_ms: float | None, state_ms: float | None, measure: bool = False):
    """``sc`` with the declared delays of the command line in place of its planner.delays
    (``measure``: switched on, else as the scenario says)."""
    delays = sc.planner.delays
    if measure:
        delays = dataclasses.replace(delays, measure=True)
    if actuation_ms is not None:
        delays = dataclasses.replace(delays, actuation_ms=actuation_ms)
    if state_ms is not None:
        delays = dataclasses.replace(delays, state_ms=state_ms)
    return dataclasses.replace(sc, planner=dataclasses.replace(sc.planner, delays=delays))


def _await_go() -> None:
    """--standby: announce readiness and block until a line arrives on standard input."""
    print("standby: ready", flush=True)
    if not sys.stdin.readline():
        typer.echo("standby: standard input closed before the go; exiting unconnected", err=True)
        raise typer.Exit(1)
    log.info("standby: taking over")
