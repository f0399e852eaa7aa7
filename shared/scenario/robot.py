"""The ``robot`` section: the robot by name, or its model and robot file in the scenario."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from shared.config import (
    Section,
    vector,
)
from shared.robots import ROBOT_KEYS, ROBOTS, RobotSpec, get_robot, load_robot, parse_robot


@dataclass(frozen=True)
class RobotConfig:
    """``robot:``: the robot (its name, and what its robot file says) and its start."""

    model: str  # the robot's name: a robot file's stem, or the MJCF's for a robot declared inline
    qpos: tuple[float, ...] | None = None  # initial joint positions; None = the model's default
    # what the robot file says (frame, controls, safe control); by default, get_robot(model)
    spec: RobotSpec = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.spec is None:
            object.__setattr__(self, "spec", get_robot(self.model))


def read_robot(s: Section) -> RobotConfig:
    """``robot:``: ``model:`` a robot's name (``m3p2i list robots``) or the path of a robot file
    (relative to the scenario's folder), or the keys of a robot file themselves (``mjcf``,
    ``frame``, ``controls``, ...; the MJCF relative to the scenario's folder); ``qpos``: the
    initial joint positions."""
    folder = Path(s.source).parent
    inline = [k for k in ROBOT_KEYS if s.has(k)]
    if inline and s.has("model"):
        raise s.error(
            inline[0],
            "a robot is either named (model:) or declared here, not both",
            expected="model: NAME, or the keys of a robot file (mjcf, frame, controls, ...)",
        )
    if inline:
        mjcf = s.data.get("mjcf")
        spec = parse_robot(s, Path(mjcf).stem if isinstance(mjcf, str) else "robot", folder)
        model = spec.name
    else:
        model = s.req(
            "model", str, "a robot's name, a robot file, or the robot's own keys (mjcf, ...)"
        )
        spec = _named_robot(s, model, folder)
    qpos = s.opt("qpos", None, vector(), "a list of numbers")
    s.done()
    return RobotConfig(model=model, qpos=qpos, spec=spec)


def _named_robot(s: Section, model: str, folder: Path) -> RobotSpec:
    """``robot.model``: a robot file's path (relative to the scenario's folder first),
    ``NAME.yaml`` in the ``robots`` folder beside the scenario's folder, then a robot by name
    (:func:`shared.robots.get_robot`: the user's robot folders, the shipped robots). A faulty
    robot file raises its own error (its file, key and value)."""
    if model.endswith((".yaml", ".yml")) or "/" in model or os.sep in model:
        for path in (folder / model, Path(model)):
            if path.is_file():
                return load_robot(path)
        raise s.error("model", "no such robot file", model, f"a file; looked in {folder}")
    beside = folder.parent / "robots" / f"{model}.yaml"
    if beside.is_file():
        return load_robot(beside)
    try:
        return get_robot(model)
    except KeyError:
        raise s.error(
            "model",
            "unknown robot",
            model,
            f"one of: {', '.join(sorted(ROBOTS))}, or a robot file (a path relative to the "
            "scenario)",
        ) from None
