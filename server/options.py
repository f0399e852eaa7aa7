"""The world's command-line options, shared by ``m3p2i-server`` and ``m3p2i run`` (declared
once here, as ``Annotated`` types; a command sets only the default): the mode and what each mode
alone takes (:func:`mode_conflicts` refuses the rest), ``--faults`` and the file or profile it
names (:func:`load_faults`), MuJoCo's window; and the run folder and the one-line summary both
print at an episode's end. Light to import (typer and the scenario schema, not the world's
simulation): ``m3p2i`` reads it too."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from shared.config import ConfigError, load_yaml
from shared.scenario.faults import PROFILES, FaultConfig, parse_faults, read_old_name

MODES = ("lockstep", "realtime")
Mode = Annotated[
    str,
    typer.Option(
        "--mode",
        help="lockstep: the world steps only when the command for its latest state "
        "arrives (deterministic). realtime: it steps on the wall clock, playing the newest "
        "command's plan.",
    ),
]


def mode_conflicts(
    mode: str, plan_every: int = 1, max_rate: float = 0.0, realtime_factor: float = 1.0
) -> list[tuple[str, str, object, str]]:
    """The options that mean nothing in ``mode``, each as ``(key, why, value, expected)`` (the
    bench names the key, ``m3p2i run`` and ``m3p2i-server`` its flag): a combination that
    would be silently ignored is refused instead."""
    if mode not in MODES:
        return [("mode", "unknown mode", mode, " or ".join(MODES))]
    out: list[tuple[str, str, object, str]] = []
    if max_rate and mode != "realtime":
        out.append(
            (
                "max_rate",
                "only a real-time world lets a planner fall behind",
                max_rate,
                "mode: realtime (lock-step: plan_every)",
            )
        )
    if realtime_factor != 1.0 and mode != "realtime":
        out.append(
            (
                "realtime_factor",
                "only a real-time world has a wall clock to follow",
                realtime_factor,
                "mode: realtime",
            )
        )
    if plan_every > 1 and mode != "lockstep":
        out.append(
            (
                "plan_every",
                "only a lock-step world plays a plan for a set number of steps",
                plan_every,
                "1 with mode: realtime",
            )
        )
    return out


PlanEvery = Annotated[
    int,
    typer.Option(
        "--plan-every",
        min=1,
        help="lockstep: world steps played per command (its plan's knots by "
        "time). K > 1 emulates, repeatably, a planner K times slower than a real-time world.",
    ),
]
RealtimeFactor = Annotated[
    float,
    typer.Option(
        "--realtime-factor",
        min=0.01,
        max=100.0,
        help="realtime: simulated seconds per wall second; 0.5 runs "
        "the world at half speed, so every planner rate counts double against it.",
    ),
]
Faults = Annotated[
    str | None,
    typer.Option(
        "--faults",
        help="Simulated faults for the world, to rehearse a robot "
        f"(docs/faults.md): a fault profile ({', '.join(PROFILES)}) or a YAML file of faults: keys "
        "(delays, noise, dropped states, withheld velocities, control period, model mismatch, "
        "binary gripper). Replaces the scenario's own faults: section. Only the world is told: the "
        "planner keeps the nominal model (m3p2i run --compensate declares the delays to it). "
        "lockstep: faults drawn from --seed, delays in world steps (repeatable); realtime: "
        "wall-clock delays.",
    ),
]
OldFaults = Annotated[str | None, typer.Option("--hardware", hidden=True)]  # deprecated
Window = Annotated[
    bool,
    typer.Option(
        "--window/--no-window",
        help="Open MuJoCo's own viewer window on "
        "the world's machine (needs a display); drag objects in it to disturb the world.",
    ),
]
OldWindow = Annotated[bool, typer.Option("--viewer", hidden=True)]  # deprecated


def default_run_dir(scenario: str) -> Path:
    """``runs/<scenario>-<YYYYmmdd-HHMMSS>`` under the current directory."""
    return Path("runs") / f"{scenario}-{time.strftime('%Y%m%d-%H%M%S')}"


def summary_line(status: str, sim_time: float, measures: dict[str, float]) -> str:
    """One line for the end of an episode: outcome, simulated time, measures, planner Hz."""
    parts = [f"{status}", f"time {sim_time:.2f} s"]
    for k, v in measures.items():
        if k == "planner_hz":
            continue
        unit = " m" if k.startswith("distance") else ""
        parts.append(f"final {k} {v:.3f}{unit}")
    if "planner_hz" in measures:
        parts.append(f"planner {measures['planner_hz']:.1f} Hz")
    return ", ".join(parts)


def load_faults(spec: str) -> FaultConfig:
    """``--faults``'s value: a profile's name, or a YAML file holding a ``faults:`` value (a
    profile's name or a mapping; ``hardware:``, its old name, too), or that mapping at its top
    level."""
    if spec in PROFILES:
        return PROFILES[spec]
    path = Path(spec)
    if not path.is_file():
        raise ConfigError(
            "--faults",
            "",
            "neither a profile nor a file",
            spec,
            f"one of: {', '.join(PROFILES)}, or a YAML file",
        )
    raw = read_old_name(load_yaml(path), str(path))
    if isinstance(raw, dict) and set(raw) == {"faults"}:
        return parse_faults(raw["faults"], str(path))
    return parse_faults(raw, str(path), "")
