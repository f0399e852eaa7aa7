"""Robot models: an MJCF and a robot file (``NAME.yaml``) that says what the rest of the system
needs to know about it, found by name the way scenarios are (docs/scenarios.md, "Bring your own
robot").

A robot MJCF is a complete model with the robot in its worldbody; the scene builder
(:mod:`shared.scene`) loads it as the base of the scenario's `mujoco.MjSpec` and adds the world.
The robot file names the MJCF (a path relative to the robot file), the robot's frame, its
controls with their units in the MJCF's actuator order, the safe control and the actuators a safe
stop holds. It is validated once, at load, against the MJCF: every error names the file, the key
and the value. The shipped robots are the ``*.yaml`` files of this folder; a user's robots are
``NAME.yaml`` in the ``robots`` folder beside each user scenario folder
(:func:`shared.config_files.search_folders`), looked up first. A scenario may also declare its
robot in its own ``robot:`` section (:func:`parse_robot`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from shared.config import ConfigError, Section, load_yaml, string_list, vector
from shared.config_files import find

ROBOT_DIR = Path(__file__).parent

# the units a bridge may meet in command.ctrl (m3p2i layout prints them per control)
UNITS = ("m/s", "rad/s", "m", "rad", "fraction", "N", "N·m", "ignored")
# the keys of a robot file, also accepted inline in a scenario's robot: section
ROBOT_KEYS = ("mjcf", "frame", "description", "controls", "safe_ctrl", "hold_ctrl", "spheres")

# collision spheres by body: (body, ((x, y, z, r), ...)), m, in the body's frame
Spheres = tuple[tuple[str, tuple[tuple[float, float, float, float], ...]], ...]


@dataclass(frozen=True)
class RobotSpec:
    """What the rest of the system needs to know about a robot model.

    Attributes:
        name: the name scenarios use (``robot.model``): the robot file's stem.
        mjcf: the MJCF file, relative to ``folder`` (or absolute).
        frame: body (or site, prefixed ``site:``) whose pose is "the robot" for costs/observers.
        description: one line for ``m3p2i list robots`` and error messages.
        ctrl_names: actuator names in control-vector order (checked against the MJCF).
        ctrl_units: the unit of each control, in ``ctrl_names`` order, for bridges
            (``m3p2i layout``): one of :data:`UNITS`.
        safe_ctrl: the control that holds the robot still (zero velocity for velocity actuators);
            applied by the server when commands go stale, and by the planner when the task is
            done or has failed.
        hold_ctrl: actuators a safe stop leaves at their last command instead: a gripper keeps
            its grip (closing could grab a cube just released; opening would drop a held one).
            Their ``safe_ctrl`` value applies only before any command was received.
        spheres: collision spheres declared per body, replacing the ones the planner derives
            from that body's collision geoms (``planner_client.spheres``); an empty list: none.
        folder: the folder ``mjcf`` is relative to: the robot file's (the package's for a robot
            registered in Python).
        source: the robot file (or scenario) that declared the robot, for error messages; empty
            for a robot registered in Python.
    """

    name: str
    mjcf: str
    frame: str
    description: str
    ctrl_names: tuple[str, ...]
    ctrl_units: tuple[str, ...]
    safe_ctrl: tuple[float, ...]
    hold_ctrl: tuple[str, ...] = ()
    spheres: Spheres = ()
    folder: Path = field(default=ROBOT_DIR, compare=False)
    source: str = field(default="", compare=False)

    @property
    def path(self) -> Path:
        """The MJCF file (``..`` resolved, links kept)."""
        return Path(os.path.normpath(self.folder / self.mjcf))

    @property
    def shipped(self) -> bool:
        """A robot of the package (its file in ``shared/robots``, or registered in Python)."""
        return not self.source or Path(self.source).resolve().parent == ROBOT_DIR.resolve()

    def safe_stop(self, last_ctrl: Sequence[float] | None = None) -> np.ndarray:
        """The control of a safe stop ``[nu]``: ``safe_ctrl``, with the ``hold_ctrl`` actuators
        at ``last_ctrl`` (the last command applied) when given. The one definition both the
        server (stale commands) and the planner (task done or failed) use."""
        ctrl = np.array(self.safe_ctrl, dtype=float)
        if last_ctrl is not None:
            hold = [self.ctrl_names.index(n) for n in self.hold_ctrl]
            ctrl[hold] = np.asarray(last_ctrl, dtype=float)[hold]
        return ctrl


# robots registered in Python (register); the shipped ones are files, read on demand
_REGISTERED: dict[str, RobotSpec] = {}


def register(spec: RobotSpec) -> RobotSpec:
    """Register a robot from Python (a robot file is the usual way: no code needed)."""
    if spec.name in _REGISTERED:
        raise ValueError(f"robot {spec.name!r} registered twice")
    if len(spec.ctrl_units) != len(spec.ctrl_names):
        raise ValueError(
            f"robot {spec.name!r}: {len(spec.ctrl_units)} ctrl_units for "
            f"{len(spec.ctrl_names)} ctrl_names; one unit per control"
        )
    _REGISTERED[spec.name] = spec
    return spec


def registered() -> dict[str, RobotSpec]:
    """The robots registered in Python, by name."""
    return dict(_REGISTERED)


def find_robot(name_or_path: str | os.PathLike) -> Path:
    """A robot file: the path as given, else ``NAME.yaml`` in the user's robot folders, then the
    shipped ones (:func:`shared.config_files.find`)."""
    return find(name_or_path, "robots")


def get_robot(name_or_path: str | os.PathLike) -> RobotSpec:
    """A robot by name (a robot file found by :func:`find_robot`, or one registered in Python)
    or by the path of its robot file. Raises :class:`KeyError` for an unknown name and
    :class:`~shared.config.ConfigError` for a faulty robot file."""
    if str(name_or_path) in _REGISTERED:
        return _REGISTERED[str(name_or_path)]
    try:
        path = find_robot(name_or_path)
    except ConfigError:
        raise KeyError(
            f"unknown robot {str(name_or_path)!r}; known: {', '.join(sorted(ROBOTS))}"
        ) from None
    return load_robot(path)


def load_robot(path: str | os.PathLike) -> RobotSpec:
    """The robot of a robot file, validated against its MJCF; read again only when the robot
    file or the MJCF changed."""
    path = Path(path).absolute()
    cached = _CACHE.get(path)
    if cached is not None and cached[1] == _version(path, cached[0].path):
        return cached[0]
    section = Section(load_yaml(path), str(path))
    spec = parse_robot(section, path.stem, path.parent)
    section.done()
    _CACHE[path] = (spec, _version(path, spec.path))
    return spec


# a robot file -> its robot, and the (mtime, size) of the robot file and of its MJCF then
_CACHE: dict[Path, tuple[RobotSpec, tuple]] = {}


def _version(*paths: Path) -> tuple:
    return tuple((p.stat().st_mtime_ns, p.stat().st_size) if p.is_file() else None for p in paths)


def parse_robot(s: Section, name: str, folder: Path) -> RobotSpec:
    """A robot from the keys of a robot file (:data:`ROBOT_KEYS`), read from ``s`` (a robot file,
    or a scenario's ``robot:`` section; the caller calls ``s.done()`` when the section holds
    other keys too), its MJCF relative to ``folder``; checked against the MJCF: the controls are
    its actuators in order, the frame one of its bodies or sites."""
    mjcf = s.req("mjcf", str, "the robot's MJCF file, relative to this file")
    frame = s.req("frame", str, "a body of the MJCF, or site:NAME")
    description = s.opt("description", "", str)
    controls = s.req("controls", dict, "a mapping actuator: unit, in the MJCF's actuator order")
    if not controls:
        raise s.error("controls", "no controls", controls, "at least one actuator: unit")
    for actuator, unit in controls.items():
        if unit not in UNITS:
            raise s.error(
                f"controls.{actuator}", "unknown unit", unit, f"one of: {', '.join(UNITS)}"
            )
    names = tuple(str(n) for n in controls)
    safe = s.opt(
        "safe_ctrl", (0.0,) * len(names), vector(len(names)), f"{len(names)} numbers, one a control"
    )
    hold = s.opt("hold_ctrl", (), string_list, "a list of control names")
    for i, n in enumerate(hold):
        if n not in names:
            raise s.error(f"hold_ctrl[{i}]", "not a control", n, f"one of: {', '.join(names)}")
    spec = RobotSpec(
        name=name,
        mjcf=mjcf,
        frame=frame,
        description=description,
        ctrl_names=names,
        ctrl_units=tuple(controls.values()),
        safe_ctrl=safe,
        hold_ctrl=hold,
        spheres=_read_spheres(s),
        folder=folder,
        source=s.source,
    )
    _check_mjcf(spec, s)
    return spec


def _read_spheres(s: Section) -> Spheres:
    """``spheres:``, body: a list of ``[x, y, z, r]`` (finite; r > 0, m, in the body's frame);
    the bodies are checked against the MJCF by :func:`_check_mjcf`."""
    raw = s.opt("spheres", {}, dict, "a mapping body: [[x, y, z, r], ...]")
    out = []
    for body, items in raw.items():
        if not isinstance(items, list):
            raise s.error(f"spheres.{body}", "wrong type", items, "a list of [x, y, z, r]")
        spheres = []
        for i, item in enumerate(items):
            key = f"spheres.{body}[{i}]"
            try:
                spheres.append(vector(4)(item))
            except ValueError as exc:
                raise s.error(key, str(exc), item, "[x, y, z, r], m, r > 0") from None
            if not spheres[-1][3] > 0:
                raise s.error(key, "radius must be > 0", item, "[x, y, z, r], m, r > 0")
        out.append((str(body), tuple(spheres)))
    return tuple(out)


def _check_mjcf(spec: RobotSpec, s: Section) -> None:
    """The robot's MJCF exists and parses, has the controls as its actuators in that order, and
    the frame as a body or a site; each error names the key, the value and the MJCF."""
    path = spec.path
    if not path.is_file():
        raise s.error("mjcf", "no such MJCF file", spec.mjcf, f"a file; looked for {path}")
    try:
        model = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo raises ValueError and others, with the parser's reason
        raise s.error("mjcf", f"MuJoCo cannot read it: {exc}", spec.mjcf) from None
    actuators = [a.name for a in model.actuators]
    listed = ", ".join(a or "(unnamed)" for a in actuators) or "(none)"
    for n in spec.ctrl_names:
        if n not in actuators:
            raise s.error(
                f"controls.{n}", f"no actuator {n!r} in {path}", n, f"its actuators: {listed}"
            )
    if tuple(actuators) != spec.ctrl_names:
        missing = [a or "(unnamed)" for a in actuators if a not in spec.ctrl_names]
        raise s.error(
            "controls",
            f"not the actuators of {path} in their order"
            + (f" ({', '.join(missing)} not listed)" if missing else ""),
            list(spec.ctrl_names),
            listed,
        )
    try:
        compiled = model.compile()
    except Exception as exc:  # a robot MJCF is a complete model: it must compile alone
        raise s.error("mjcf", f"MuJoCo cannot compile it: {exc}", spec.mjcf) from None
    _check_actuators(spec, s, compiled)
    bodies = [b.name for b in model.bodies if b.name and b.name != "world"]
    for body, _ in spec.spheres:
        if body not in bodies:
            raise s.error(
                f"spheres.{body}",
                f"no body {body!r} in {path}",
                body,
                f"one of: {', '.join(bodies)}",
            )
    kind, frame = (
        ("site", spec.frame[5:]) if spec.frame.startswith("site:") else ("body", spec.frame)
    )
    names = [x.name for x in (model.sites if kind == "site" else model.bodies)]
    if frame not in names:
        raise s.error(
            "frame",
            f"no {kind} {frame!r} in {path}",
            spec.frame,
            f"one of its {kind}s: {', '.join(n for n in names if n) or '(none)'}",
        )


# the units each kind of actuator takes: a velocity servo a speed, a position servo a place
# (or a gripper's opening), a motor a force (or a share of one, as suction)
UNITS_OF = {
    "velocity servo": ("m/s", "rad/s", "ignored"),
    "position servo": ("m", "rad", "fraction", "ignored"),
    "motor": ("N", "N·m", "fraction", "ignored"),
}


def actuator_kind(model: mujoco.MjModel, i: int) -> str | None:
    """What actuator ``i`` of ``model`` is, from its bias (MuJoCo's shortcuts ``velocity``,
    ``position`` and ``motor`` set it so): a key of :data:`UNITS_OF`, or None for any other
    (filtered, general with both gains), whose unit is the robot file's to say."""
    bias = model.actuator_biasprm[i]
    if model.actuator_dyntype[i] != mujoco.mjtDyn.mjDYN_NONE:
        return None
    if model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_NONE:
        return "motor"
    if model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE:
        if bias[1] == 0 and bias[2] != 0:
            return "velocity servo"
        if bias[1] != 0:
            return "position servo"
    return None


def _check_actuators(spec: RobotSpec, s: Section, model: mujoco.MjModel) -> None:
    """Every control has a finite, non-empty range that MuJoCo enforces (the planner samples
    within it and the world clips to it: without one, a NaN or an unbounded control reaches the
    robot), ``safe_ctrl`` lies within it, and its unit fits its actuator's kind."""
    for i, name in enumerate(spec.ctrl_names):
        lo, hi = (float(v) for v in model.actuator_ctrlrange[i])
        where = f"actuator {name!r} of {spec.path}"
        expected = 'ctrlrange="LOW HIGH", finite, LOW < HIGH (and ctrllimited not false)'
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise s.error(f"controls.{name}", f"{where}: ctrlrange not finite", [lo, hi], expected)
        if not lo < hi:
            raise s.error(f"controls.{name}", f"{where}: empty ctrlrange", [lo, hi], expected)
        if not model.actuator_ctrllimited[i]:
            raise s.error(
                f"controls.{name}", f"{where}: its ctrlrange is not enforced", [lo, hi], expected
            )
        if not lo <= spec.safe_ctrl[i] <= hi:
            raise s.error(
                f"safe_ctrl[{i}]",
                f"outside the ctrlrange of {where}",
                spec.safe_ctrl[i],
                f"a value in [{lo:g}, {hi:g}]",
            )
        kind = actuator_kind(model, i)
        unit = spec.ctrl_units[i]
        if kind is not None and unit not in UNITS_OF[kind]:
            raise s.error(
                f"controls.{name}",
                f"{where} is a {kind}, not driven in {unit}",
                unit,
                f"one of: {', '.join(UNITS_OF[kind])}",
            )


class _Robots(Mapping[str, RobotSpec]):
    """Every robot by name: the robot files of the searched folders (the user's first) and the
    robots registered in Python, read on access (the folders depend on ``M3P2I_SCENARIOS`` and
    the current folder)."""

    def _names(self) -> list[str]:
        from shared.config_files import entries

        return sorted({*_REGISTERED, *(e.name for e in entries("robots"))})

    def __getitem__(self, name: str) -> RobotSpec:
        return get_robot(name)

    def __contains__(self, name: Any) -> bool:
        return isinstance(name, str) and name in self._names()

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())


ROBOTS: Mapping[str, RobotSpec] = _Robots()
