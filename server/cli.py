"""``m3p2i-server``: the world process."""

from __future__ import annotations

import logging
import math
import os
import signal
from pathlib import Path
from typing import Annotated

import mujoco
import numpy as np
import typer

from server.app import AddressUnavailable, ServerOptions, WorldServer
from server.interface import WorldError, WorldLoadError, load_world_class
from server.keys import load_world_keys
from server.options import (
    MODES,
    Faults,
    Mode,
    OldFaults,
    OldWindow,
    PlanEvery,
    RealtimeFactor,
    Window,
    default_run_dir,
    load_faults,
    mode_conflicts,
    summary_line,
)
from server.world import SimWorld
from server.world_check import scenario_errors
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
from shared.config import ConfigError
from shared.endpoints import DEFAULT_HOST, DEFAULT_PORT, Endpoints
from shared.protocol import MAX_SEED
from shared.scenario import load_scenario

app = typer.Typer(add_completion=False)

HELP = (
    "Run the world: a MuJoCo simulation of a scenario that publishes its state over ZeroMQ and "
    "applies the planner's commands.\n\n"
    "Start it, then start `m3p2i-planner` with the same scenario in a second terminal. "
    "Across machines: `m3p2i keys DIR`, then `--host 0.0.0.0 --keys DIR` here and "
    "`--host THIS_MACHINE --keys DIR` on the planner (ZeroMQ CURVE: authenticated, "
    "encrypted). "
    "A robot instead of the simulation: `--world package.module:Class`, a bridge class of your "
    "own (docs/bridge.md); this process then serves it, handshake, watchdog and log included. "
    "Exit code: 0 on success, 1 on time-out or stop, 2 on a configuration error."
)

log = logging.getLogger("m3p2i.server")


LogFile = Annotated[
    Path | None,
    typer.Option(
        "--log",
        help="Episode log (JSON lines); '{seed}' in it (e.g. seed-{seed:03d}) becomes the "
        "episode's seed. Default: runs/<scenario>-<time>/episode.jsonl",
    ),
]
CommandTimeout = Annotated[
    float,
    typer.Option(
        min=0.001,
        help="realtime: seconds after which a missing command makes the robot hold still.",
    ),
]
Republish = Annotated[
    float,
    typer.Option(
        min=0.001,
        help="lockstep: re-send the state waiting for its command this often (seconds), for a "
        "planner that subscribed late or lost it.",
    ),
]
KeepServing = Annotated[
    bool,
    typer.Option(
        help="After the episode, keep the sockets open and wait for a control 'reset' with a "
        "seed, which begins the next episode (new session, new log: --log must hold "
        "'{seed}'); 'shutdown' exits. What warm bench workers use; pair it with m3p2i-planner "
        "--keep-running.",
    ),
]
CheckOnly = Annotated[
    bool,
    typer.Option(
        "--check",
        help="Only check the scenario (every error of the file, model names included) and "
        "--world's class, and exit: 0 sound, 2 faulty.",
    ),
]
WorldSeed = Annotated[
    int,
    typer.Option(
        min=0,
        max=MAX_SEED,
        help="Seed of the scenario's randomised start (world.randomize) and of the simulated "
        "faults (--faults).",
    ),
]
WorldClass = Annotated[
    str | None,
    typer.Option(
        "--world",
        help="The world to serve instead of the MuJoCo simulation: package.module:Class naming "
        "a subclass of server.bridge.Bridge (a robot) or server.interface.World, imported from "
        "the installed packages, PYTHONPATH or the current directory (docs/bridge.md). A robot "
        "runs --mode realtime.",
    ),
]


@app.command(help=HELP)
def main(
    scenario: ScenarioOption,
    mode: Mode = "lockstep",
    host: Host = DEFAULT_HOST,
    keys: Keys = None,
    insecure: Insecure = False,
    port: Port = DEFAULT_PORT,
    log_file: LogFile = None,
    command_timeout: CommandTimeout = 0.5,
    realtime_factor: RealtimeFactor = 1.0,
    republish: Republish = 0.2,
    plan_every: PlanEvery = 1,
    keep_serving: KeepServing = False,
    window: Window = False,
    check: CheckOnly = False,
    seed: WorldSeed = 0,
    world: WorldClass = None,
    faults: Faults = None,
    verbose: Verbose = False,
    parent_pid: ParentPid = None,
    hardware: OldFaults = None,
    viewer: OldWindow = False,
) -> None:
    setup_logging(verbose, "m3p2i.server")
    faults = renamed(faults, hardware, "--faults", "--hardware", None)
    window = renamed(window, viewer, "--window", "--viewer", False)
    if mode not in MODES:
        raise typer.BadParameter("must be 'lockstep' or 'realtime'", param_hint="--mode")
    # as m3p2i run refuses them: an option of the other mode would be silently ignored
    for key, why, value, expected in mode_conflicts(mode, plan_every, 0.0, realtime_factor):
        expected = expected.replace("mode: ", "--mode ")
        _exit(f"error: --{key.replace('_', '-')} {value:g}: {why} (expected {expected})")
    # before anything else: an exposed robot is refused at once (--check checks no keys)
    world_keys = (
        None
        if check
        else keys_or_exit({"--host": host}, keys, insecure, load_world_keys, log.warning)
    )
    world_class, fault_config = _checked_or_exit(scenario, world, faults, check)
    _serving_or_exit(keep_serving, log_file, window)
    sc = load_scenario(scenario)
    opts = ServerOptions(
        mode=mode,
        command_timeout=command_timeout,
        realtime_factor=realtime_factor,
        republish=republish,
        plan_every=plan_every,
        keep_serving=keep_serving,
    )
    try:
        server = WorldServer(
            sc,
            Endpoints(host, port),
            log_file or default_run_dir(sc.name) / "episode.jsonl",
            opts,
            seed=seed,
            keys=world_keys,
            world=world_class,
            faults=fault_config,
        )
    except ConfigError as exc:  # e.g. a metrics frame the compiled model lacks
        _exit(f"error: {exc}")
    except WorldError as exc:  # a bridge that cannot reach its robot
        _exit(f"error: --world {world}: {exc}")
    except AddressUnavailable as exc:
        _exit(f"error: {exc} (--host, --port: the world needs ports PORT..PORT+3 free)")
    if window:
        _open_window(server, world)
    _serve(server, world, parent_pid)


def _exit(message: str, code: int = 2) -> None:
    typer.echo(message, err=True)
    raise typer.Exit(code)


def _checked_or_exit(scenario: str, world: str | None, faults: str | None, check: bool):
    """``(world class, faults)`` once the scenario, ``--world``'s class and ``--faults`` are
    sound; every error of them printed and exit 2 otherwise (with ``--check``: exit 0 when
    sound)."""
    try:  # --check checks it too
        world_class, world_error = (SimWorld if world is None else load_world_class(world)), None
    except WorldLoadError as exc:
        world_class, world_error = None, exc
        typer.echo(f"error: {exc}", err=True)
    errors = scenario_errors(scenario)  # every error of the file, before anything starts
    fault_config = None
    if faults is not None:
        try:
            fault_config = load_faults(faults)
        except ConfigError as exc:
            errors = [*errors, exc]
    print_errors(errors, err=not check)
    if errors or world_error or check:
        raise typer.Exit(2 if errors or world_error else 0)
    return world_class, fault_config


def _serving_or_exit(keep_serving: bool, log_file: Path | None, window: bool) -> None:
    """A kept world needs a log per episode and no MuJoCo window (it shows one world)."""
    if keep_serving and (log_file is None or "{seed" not in str(log_file)):
        _exit(
            "error: --keep-serving needs a --log holding '{seed}' (e.g. "
            "runs/x/seed-{seed:03d}/episode.jsonl): each episode gets its own log"
        )
    if keep_serving and window:
        _exit(
            "error: --keep-serving builds a new world for each episode; MuJoCo's window "
            "shows one: use `m3p2i view` (the browser view) instead"
        )


def _open_window(server: WorldServer, world: str | None) -> None:
    """MuJoCo's passive viewer on the world's data, where there is a display and data."""
    if server.world.data is None:
        log.warning("the world %s keeps no MuJoCo data to show: running without the viewer", world)
    elif os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        import mujoco.viewer

        # the side panels would cover most of the window it opens with (Tab and Shift+Tab
        # show them)
        server.viewer = mujoco.viewer.launch_passive(
            server.world.model, server.world.data, show_left_ui=False, show_right_ui=False
        )
        frame_viewer(server.viewer, server.world.model, server.world.data)
    else:
        log.warning("no display found: running without the viewer")


def _serve(server: WorldServer, world: str | None, parent_pid: int | None) -> None:
    """Serve until the episode (or, kept, the last one) ends, or launcher ``parent_pid`` is
    gone; exit 0 on success, 1 otherwise."""
    # a supervisor (systemd, the launcher's stop, a soak test's restart) stops the world with
    # SIGTERM: end the episode as Ctrl-C does, so the log still gets its summary
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, server.interrupt)
    collector_back()
    stop_with_parent(parent_pid)
    try:
        outcome = server.run()
    except WorldError as exc:  # the world failed mid-episode: stopped, the summary written
        typer.echo(f"error: --world {world}: {exc}", err=True)
        typer.echo(f"episode log: {server.log.path}")
        raise typer.Exit(1) from None
    if server.viewer is not None:
        server.viewer.close()
    typer.echo(summary_line(outcome.status, outcome.time, outcome.measures))
    typer.echo(f"episode log: {server.log.path}")
    raise typer.Exit(0 if outcome.status == "success" else 1)


def frame_viewer(viewer, model, data) -> None:
    """Point the passive viewer's free camera at the scene (:func:`shared.scene.scene_framing`)
    from the front, above (as m3p2i record's videos): MuJoCo's default frames the whole model,
    floor included, and a Panda's scene then opens looking at the table's edge."""
    centre, radius = scene_framing(model, data)
    half_fov = math.radians(model.vis.global_.fovy) / 2
    with viewer.lock():
        viewer.cam.lookat[:] = centre
        # bounding spheres overstate boxes (a table by 40 %): 0.75 of the distance that would
        # fit them all still shows every geom
        viewer.cam.distance = 0.75 * radius / math.sin(half_fov)
        viewer.cam.azimuth, viewer.cam.elevation = 150.0, -30.0


def scene_framing(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, float]:
    """Centre ``[3]`` and radius of what a camera should frame, after kinematics: every geom
    by its bounding sphere, a wall (a plane not facing up) by its drawn size; the ground (a
    plane facing up) is left out, or a Panda on its table would be a speck on 10 m of floor."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for g in range(model.ngeom):
        pos, rot = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            if rot[2, 2] > 0.99:
                continue
            sx, sy = model.geom_size[g][:2]
            corners = np.array([[x, y, 0.0] for x in (-sx, sx) for y in (-sy, sy)])
            points = corners @ rot.T + pos
        else:
            r = model.geom_rbound[g]
            points = np.array([pos - r, pos + r])
        lo, hi = np.minimum(lo, points.min(0)), np.maximum(hi, points.max(0))
    if not np.all(np.isfinite(lo)):
        return np.zeros(3), 1.0
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 0.1)
