"""A scenario file read whole: ``base:`` files merged, every section read with every error
collected, the hash both processes compare."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.config import (
    ConfigError,
    ErrorLog,
    Section,
    load_yaml,
    string_list,
)
from shared.config_files import find, shipped
from shared.robots import RobotSpec
from shared.scenario.episode import EpisodeConfig, MetricsConfig, read_episode, read_metrics
from shared.scenario.faults import NOMINAL, OLD_NAME, FaultConfig, parse_faults, read_old_name
from shared.scenario.guide import GuideConfig, check_grid, parse_guide
from shared.scenario.objectives import ObjectiveConfig, read_includes, read_objectives
from shared.scenario.planner import PlannerConfig, read_planner
from shared.scenario.robot import RobotConfig, read_robot
from shared.scenario.sensors import SensorConfig, read_sensors
from shared.scenario.task import ObserverConfig, read_observers, read_plan
from shared.scenario.team import Member, read_team, team_robot
from shared.scenario.world import WorldConfig, declared_world, read_world
from shared.task_template import TaskTemplate, parse_task

SCENARIO_DIR = shipped("scenarios")  # the scenarios shipped with m3p2i


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    hash: str
    robot: RobotConfig
    world: WorldConfig
    episode: EpisodeConfig
    planner: PlannerConfig
    objectives: dict[str, ObjectiveConfig]
    modes: tuple[str, ...]  # fixed modes (when there is no task template)
    task: TaskTemplate | None = None
    observers: dict[str, ObserverConfig] = field(default_factory=dict)
    # the plan interface, YAML key ``plan``: task action -> the objective that executes it
    action_objectives: dict[str, str] = field(default_factory=dict)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    # the world server's simulated faults (docs/faults.md); the planner keeps the nominal model
    faults: FaultConfig = NOMINAL
    # the user's modules of cost terms and observer predicates, imported by the planner
    # (planner_client.plugins): NAME.py beside the scenario, else a module name; never the world
    plugins: tuple[str, ...] = ()
    raw: dict = field(repr=False, default_factory=dict)
    guide: GuideConfig | None = None  # a global path the planner's terms follow (guide.py)
    # range sensors the world simulates; their readings travel with its states (protocol 3)
    sensors: tuple[SensorConfig, ...] = ()
    # ``robots:`` (shared/scenario/team.py): every robot of the world; empty for one robot
    team: tuple[Member, ...] = ()
    member: str = ""  # in a robot's view: its name (``robot`` is then its own robot)
    members: dict[str, Scenario] = field(default_factory=dict, repr=False)  # the views by name


def find_scenario(name_or_path: str | os.PathLike) -> Path:
    """A path as given, else ``NAME.yaml`` in the user's scenario folders, then the shipped ones."""
    return find(name_or_path, "scenarios")


def load_scenario(name_or_path: str | os.PathLike) -> Scenario:
    """Load and validate a scenario; raises :class:`ConfigError` naming file, key, value (or
    :class:`~shared.config.ConfigErrors` with every error of the file)."""
    reading = read_scenario(name_or_path)
    reading.raise_if_any()
    return reading.scenario


@dataclass
class ScenarioReading:
    """A scenario file read with every error collected instead of raised at the first.

    ``scenario`` is what could be read (None when not even a robot could be read: no file,
    bad YAML, an unknown robot); faulty parts are left out of it, so it serves only checks.
    ``model_ok``: the robot and the world were read without error, so the compiled model is
    the one the file describes and model checks (frames, actuators, sensors) mean something.
    Without it, the scenario's world is a stand-in of the names the file declares (its objects,
    the arena's walls): enough to check the names the file uses, against them and the robot's
    bodies and sites (:mod:`shared.scenario_check`).
    """

    scenario: Scenario | None
    errors: list[ConfigError]
    model_ok: bool

    def raise_if_any(self) -> None:
        log = ErrorLog()
        log.errors = list(self.errors)
        log.raise_if_any()


def read_scenario(name_or_path: str | os.PathLike) -> ScenarioReading:
    """Read a scenario, collecting every load-time error (see :class:`ScenarioReading`)."""
    errors = ErrorLog()
    path = errors.call(find_scenario, name_or_path)
    raw = errors.call(load_yaml, path) if path is not None else None
    if raw is not None:
        raw = errors.call(with_base, raw, str(path))
    if raw is None:
        return ScenarioReading(None, errors.errors, False)
    return _read(raw, str(path), errors)


def with_base(raw: Any, source: str, _seen: tuple[Path, ...] = ()) -> Any:
    """``base: NAME or path`` (a path relative to ``source``'s folder first): the scenario
    ``raw`` over the one it names, mappings merged key by key; a list or a value replaces the
    base's, ``null`` removes the key. ``name`` is not inherited (default: the file's stem). A
    base may have its own base. Raises :class:`ConfigError` naming the file and the base.
    Every file's ``hardware:``, the old name of ``faults:``, is read as ``faults:`` first."""
    raw = read_old_name(raw, source)
    if not isinstance(raw, dict) or "base" not in raw:
        return raw
    spec = raw["base"]
    if not isinstance(spec, str) or not spec:
        raise ConfigError(
            source, "base", "not a scenario name or path", spec, "e.g. base: pick_place"
        )
    me = Path(source).resolve()
    near = [Path(source).parent / spec, Path(source).parent / f"{spec}.yaml"]
    try:
        path = next((p for p in near if p.is_file()), None) or find_scenario(spec)
        path = path.resolve()
    except ConfigError:
        raise ConfigError(
            source, "base", "no such scenario", spec, "a scenario name (m3p2i list) or a YAML path"
        ) from None
    if path == me and (shipped("scenarios") / f"{spec}.yaml").is_file():
        path = (
            shipped("scenarios") / f"{spec}.yaml"
        ).resolve()  # a user's file over the shipped one
    if path in _seen or path == me:
        raise ConfigError(
            source,
            "base",
            "a scenario cannot be its own base",
            spec,
            "a chain of bases without a loop",
        )
    base = with_base(load_yaml(path), str(path), _seen + (me,))
    if not isinstance(base, dict):
        raise ConfigError(
            str(path),
            "",
            "a scenario must be a mapping",
            type(base).__name__,
            "keys such as name, robot, world",
        )
    merged = _merge(base, {k: v for k, v in raw.items() if k != "base"})
    if "name" not in raw:
        merged.pop("name", None)
    return merged


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def scenario_hash(
    raw: dict, included: Sequence[dict] = (), robots: Sequence[RobotSpec] = (), source: str = ""
) -> str:
    """Hash of the scenario's content, of the objective files it includes, of its robots' MJCF
    files and of a robot file of the user's (the shipped ones are part of the package, and a
    shipped scenario keeps the hash it had before robots were files). ``faults:`` is hashed under
    its old name, ``hardware:``: a scenario keeps its hash (bench results, logs, an older peer's)
    whichever name it uses, and so are the other renamed keys (:data:`HASHED_AS`)."""
    raw = _hashed_spelling(raw)
    h = hashlib.sha256(json.dumps(raw, sort_keys=True, default=str).encode())
    for inc in included:
        h.update(json.dumps(inc, sort_keys=True, default=str).encode())
    for robot in robots:
        h.update(robot.path.read_bytes())
        if robot.source and robot.source != source and not robot.shipped:
            h.update(Path(robot.source).read_bytes())
    return h.hexdigest()[:16]


# (path of a mapping, key or key: value today, its spelling before the rename): hashed under the
# old spelling, so that a scenario keeps its hash (bench results resume) whichever it uses
HASHED_AS = (
    ((), "faults", OLD_NAME),
    (("planner",), "tracking", "estimate"),
    (("planner", "delays"), "measure", "estimate"),
    (("planner", "model", "variants"), ("spread", "identified"), ("spread", "estimate")),
)


def _hashed_spelling(raw: dict) -> dict:
    """``raw`` with every renamed key (and value) in its old spelling; ``raw`` is not changed."""
    out = copy.deepcopy(raw)
    for path, new, old in HASHED_AS:
        node = out
        for key in path:
            node = node.get(key) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            continue
        if isinstance(new, tuple):
            (key, value), (_, old_value) = new, old
            if node.get(key) == value:
                node[key] = old_value
        elif new in node:
            node[old] = node.pop(new)
    return out


def parse_scenario(raw: dict, source: str) -> Scenario:
    """A scenario from its YAML mapping; raises with every error of the file."""
    reading = _read(with_base(raw, source), source, ErrorLog())
    reading.raise_if_any()
    return reading.scenario


def _read(
    raw: dict,
    source: str,
    errors: ErrorLog,
    team: tuple[Member, ...] = (),
    member: Member | None = None,
) -> ScenarioReading:
    """Each independent part is read under ``errors``: a fault is recorded and the part left
    out, and the rest is still read. Parts that depend on a faulty one (observers on the task,
    metrics on the episode) are skipped rather than reported again. ``member``: the team's robot
    whose view this is (:func:`_read_members`)."""
    n_before = len(errors.errors)
    top = Section(raw, source)
    name = errors.call(top.req, "name", str, default=Path(source).stem)
    description = errors.call(top.opt, "description", "", str, default="")
    if top.has("robots"):
        team = errors.call(lambda: read_team(top.section("robots")), default=())
        robot = team_robot(team) if team else None
    else:
        robot = errors.call(lambda: read_robot(top.section("robot")))
        robot = member.robot if member is not None and robot is not None else robot
    world = errors.call(lambda: read_world(top.section("world"), errors))
    model_ok = len(errors.errors) == n_before
    sensors = read_sensors(top, errors)
    episode, metrics = _read_episode(top, errors)
    planner = errors.call(
        lambda: read_planner(top.section("planner", required=False)), default=PlannerConfig()
    )
    _check_timestep(world, planner, source, errors)
    faults = NOMINAL
    if top.has("faults"):  # a profile's name or a mapping
        faults = errors.call(parse_faults, top.opt("faults", None), source, default=NOMINAL)
    plugins = _read_plugins(top, errors)
    library, included = read_includes(top, errors)
    objectives = errors.call(
        lambda: read_objectives(top.section("objectives"), errors, library), default={}
    )
    task, observers, action_objectives, modes = _read_task(
        top, errors, plugins, objectives, bool(team) and member is None
    )
    _check_confirm(raw, top, planner, task, errors)
    _check_planning_model(planner, task, world, source, errors)
    _check_modes(top, modes, errors)
    guide = _read_guide(top, world, planner, errors)
    errors.call(top.done)
    if member is not None:  # a team's robot plans with its own objectives only
        used = {*modes, *action_objectives.values()}
        objectives = {k: v for k, v in objectives.items() if k in used}
    if robot is None:
        return ScenarioReading(None, errors.errors, False)
    if world is None:  # what the faulty world declares stands in, for name checks only
        world = declared_world(raw.get("world"), source)
    scenario = Scenario(
        name=name,
        description=description,
        source=source,
        hash=scenario_hash(raw, included, [m.robot.spec for m in team] or [robot.spec], source),
        robot=robot,
        world=world,
        episode=episode or EpisodeConfig(max_time=0.0, success=()),
        planner=planner,
        objectives=objectives,
        modes=modes,
        task=task,
        observers=observers,
        action_objectives=action_objectives,
        metrics=metrics,
        faults=faults,
        plugins=plugins,
        raw=raw,
        guide=guide,
        sensors=sensors,
        team=team,
        member=member.name if member is not None else "",
    )
    if team and member is None:
        scenario.members.update(_read_members(raw, source, scenario, errors))
    return ScenarioReading(scenario, errors.errors, model_ok)


def _read_episode(top: Section, errors: ErrorLog) -> tuple[EpisodeConfig | None, MetricsConfig]:
    """The ``episode`` section and the ``metrics`` that depend on it (skipped, not reported
    again, when the episode is faulty)."""
    episode = errors.call(lambda: read_episode(top.section("episode"), errors))
    if episode is None:
        top.section("metrics", required=False)
        return None, MetricsConfig()
    metrics = errors.call(
        lambda: read_metrics(top.section("metrics", required=False), episode),
        default=MetricsConfig(),
    )
    return episode, metrics


def _read_plugins(top: Section, errors: ErrorLog) -> tuple[str, ...]:
    """The ``plugins`` list: the modules a scenario's own cost terms live in."""
    return errors.call(
        top.opt,
        "plugins",
        (),
        string_list,
        "a list of Python modules: NAME.py beside the scenario, or importable module names",
        default=(),
    )


def _read_members(raw: dict, source: str, top: Scenario, errors: ErrorLog) -> dict:
    """Each robot's view of a team's scenario: its entry merged over the top level (as over a
    ``base:``) and read as a scenario of its own, with the file's hash; errors of the keys its
    entry declares are reported under ``robots.NAME``, the rest were reported already."""
    views = {}
    for m in top.team:
        found = ErrorLog()
        top_level = {k: v for k, v in raw.items() if k != "robots"}
        view = _read(_merge(top_level, raw["robots"][m.name]), source, found, top.team, m).scenario
        for e in found.errors:
            if e.path.split(".")[0].split("[")[0] in raw["robots"][m.name]:
                errors.add(
                    ConfigError(source, f"robots.{m.name}.{e.path}", e.message, e.value, e.expected)
                )
        others = [o.name for o in top.team if o.name != m.name]
        for name in view.planner.passes_through if view is not None else ():
            if name not in others:
                key = f"robots.{m.name}.planner.passes_through"
                errors.add(ConfigError(source, key, "not another robot", name, ", ".join(others)))
        if view is not None:
            views[m.name] = dataclasses.replace(view, hash=top.hash)
    return views


def _check_timestep(
    world: WorldConfig | None, planner: PlannerConfig, source: str, errors: ErrorLog
) -> None:
    """``planner.timestep`` is a whole multiple of the world's."""
    if world is not None and planner.timestep is not None:
        ratio = planner.timestep / world.timestep
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            errors.add(
                ConfigError(
                    source,
                    "planner.timestep",
                    "not a whole multiple of world.timestep",
                    planner.timestep,
                    f"{world.timestep} × 1, 2, 3, ... seconds",
                )
            )


def _read_task(
    top: Section, errors: ErrorLog, plugins: tuple[str, ...], objectives: dict, team: bool
) -> tuple[TaskTemplate | None, dict, dict, tuple[str, ...]]:
    """``task`` and what hangs on it (``observers``, ``plan``), or the fixed ``modes``:
    ``(task, observers, action_objectives, modes)``; a team's top level needs neither (each
    robot's entry has them)."""
    task = errors.call(lambda: parse_task(top.section("task"))) if top.has("task") else None
    observers, action_objectives, modes = {}, {}, ()
    if task is None and not top.has("task") and not team:
        modes = errors.call(
            top.req,
            "modes",
            string_list,
            "a list of objective names (or a task: template)",
            default=(),
        )
    else:
        modes = errors.call(
            top.opt, "modes", (), string_list, "a list of objective names", default=()
        )
        if task is not None:
            observers = errors.call(
                lambda: read_observers(top.section("observers"), task, errors, bool(plugins)),
                default={},
            )
            if team:  # each robot's entry has its own plan
                top.section("plan", required=False)
            else:
                action_objectives = errors.call(
                    lambda: read_plan(top.section("plan"), task, objectives), default={}
                )
        else:  # the task's own errors are reported; its dependants would only repeat them
            top.section("observers", required=False)
            top.section("plan", required=False)
    return task, observers, action_objectives, modes


def _check_confirm(
    raw: dict, top: Section, planner: PlannerConfig, task: TaskTemplate | None, errors: ErrorLog
) -> None:
    """``planner.confirm`` names the task's factors and their states."""
    source = top.source
    if planner is not None and planner.confirm and task is None and not top.has("task"):
        errors.add(
            ConfigError(
                source,
                "planner.confirm",
                "only a task's observers are confirmed",
                raw["planner"]["confirm"],
                "a scenario with a task: template",
            )
        )
    elif planner is not None and task is not None:
        factors = [f.name for f in task.factors]
        for key, hold in planner.confirm.items():
            if key != "*" and key not in factors:
                errors.add(
                    ConfigError(
                        source,
                        f"planner.confirm.{key}",
                        "not a factor of the task",
                        key,
                        "'*' or one of: " + ", ".join(factors),
                    )
                )
            elif isinstance(hold, dict):
                states = next(f.states for f in task.factors if f.name == key)
                for state in hold:
                    if state not in states:
                        errors.add(
                            ConfigError(
                                source,
                                f"planner.confirm.{key}.{state}",
                                "not a state of the factor",
                                state,
                                "one of: " + ", ".join(states),
                            )
                        )


def _check_planning_model(
    planner: PlannerConfig,
    task: TaskTemplate | None,
    world: WorldConfig | None,
    source: str,
    errors: ErrorLog,
) -> None:
    """``planner.model``'s objects are the world's free ones; what it attaches, and a filter of
    held poses, need each other."""
    if planner is not None and planner.model.objects and world is not None:
        free = [o.name for o in world.objects if not (o.fixed or o.perceived)]
        for obj in planner.model.objects:
            if obj not in free:
                errors.add(
                    ConfigError(
                        source,
                        f"planner.model.objects.{obj}",
                        "not a free object of the world",
                        obj,
                        "one of: " + (", ".join(free) or "(none)"),
                    )
                )
    if planner is not None and planner.model.attach:
        _check_attach(planner, task, world, source, errors)
    elif planner is not None and planner.tracking.held_filter < 1.0:
        errors.add(
            ConfigError(
                source,
                "planner.tracking.held_filter",
                "filters the pose of an attached object, and nothing is attached",
                planner.tracking.held_filter,
                "planner.model.attach, or no held_filter",
            )
        )


def _check_modes(top: Section, modes: tuple[str, ...], errors: ErrorLog) -> None:
    """Every fixed mode is an objective of the file."""
    source = top.source
    if top.has("objectives") and isinstance(top.data["objectives"], dict):
        known = list(top.data["objectives"])
        for i, m in enumerate(modes):
            if m not in known:
                errors.add(
                    ConfigError(
                        source,
                        f"modes[{i}]",
                        "not an objective of this scenario",
                        m,
                        f"one of: {', '.join(known)}",
                    )
                )


def _read_guide(
    top: Section, world: WorldConfig | None, planner: PlannerConfig, errors: ErrorLog
) -> GuideConfig | None:
    """``guide``, against the world's objects (skipped when the world is faulty), on the CPU
    rollouts only."""
    source = top.source
    guide = None
    if top.has("guide") and world is not None:
        guide = errors.call(lambda: _guide_in(top.section("guide"), world))
    elif top.has("guide"):  # the world's own errors are reported; the guide's would repeat them
        top.section("guide", required=False)
    if guide is not None and planner is not None and planner.backend != "mujoco":
        errors.add(
            ConfigError(
                source,
                "guide",
                "moves its sub-goal in the planner's model between iterations, which the "
                "warp backend copies once",
                planner.backend,
                "planner.backend: mujoco, or no guide",
            )
        )
    return guide


def _guide_in(s: Section, world: WorldConfig) -> GuideConfig:
    """``guide`` against the world's objects, its grid sized against the world's span."""
    # a perceived object is not the planner's to guide by name: its scans show it
    guide = parse_guide(s, {o.name: not (o.fixed or o.visual) for o in world.objects})
    check_grid(s, guide, world.span())
    return guide


def _check_attach(
    planner: PlannerConfig,
    task: TaskTemplate | None,
    world: WorldConfig | None,
    source: str,
    errors: ErrorLog,
) -> None:
    """An attachment needs a task state to follow, a free object, and the CPU rollouts (the
    warp backend's model is not changed between iterations)."""
    states = [st for f in task.factors for st in f.states] if task is not None else []
    # a perceived object is not in the planner's model: nothing of it to attach
    free = [o.name for o in world.objects if not (o.fixed or o.perceived)] if world else None
    for i, a in enumerate(planner.model.attach):
        path = f"planner.model.attach[{i}]"
        if a.state not in states:
            errors.add(
                ConfigError(
                    source,
                    f"{path}.while",
                    "not a state of the task's factors",
                    a.state,
                    "one of: " + ", ".join(states)
                    if states
                    else "a scenario with a task: template",
                )
            )
        if free is not None and a.object not in free:
            errors.add(
                ConfigError(
                    source,
                    f"{path}.object",
                    "not a free object of the world",
                    a.object,
                    "one of: " + (", ".join(free) or "(none)"),
                )
            )
    if planner.backend != "mujoco":
        errors.add(
            ConfigError(
                source,
                "planner.model.attach",
                "only the mujoco backend changes its model between iterations",
                planner.backend,
                "planner.backend: mujoco, or no attach",
            )
        )
