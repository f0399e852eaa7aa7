"""Plots of one episode like the thesis' Figs. A.3-A.5: object and robot trajectories (xy),
robot-object and object-goal distances over time, and the cosine of the robot-object-goal angle
(paper Eq. 16) over time. The object and the goal are the scenario's ``metrics.position`` frames;
when the "object" is the robot itself (navigation) the plot shows the robot, its distance to the
goal, and no angle. When the planner identified its model online (``planner.model.variants``), a
last panel shows each estimated factor over time against the world's true one, which the log's
header holds under a fault profile's model error (``faults_mismatch``).

Drawn with matplotlib's object API on the Agg canvas (no display, no pyplot state).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from server.evaluation import log_reader
from server.evaluation.replay import frame_tracks, resolve_frame
from shared.config import ConfigError
from shared.geometry import select_axes
from shared.scenario import Scenario
from shared.scene import compile_model

ROBOT, OBJECT, GOAL = "#ff7f0e", "#1f77b4", "#2ca02c"  # thesis colours: robot orange, object blue
ROBOT_OBJECT, OBJECT_GOAL = "#e377c2", "#9467bd"  # pink and purple distance curves


@dataclass(frozen=True)
class EpisodeSeries:
    """Frame positions over the logged steps (``[T, 3]``); ``obj`` is None when the tracked
    object is the robot itself."""

    name: str
    time: np.ndarray
    robot: np.ndarray
    obj: np.ndarray | None
    goal: np.ndarray
    object_name: str
    goal_name: str
    actions: list[tuple[float, str]]  # (time, action) where the planner's action changed
    arena: float | None  # arena half-size, for the xy limits
    # "mass.box" -> [T] the planner's estimated factor at each step (NaN before it sent one)
    model: dict[str, np.ndarray] = field(default_factory=dict)
    truth: dict[str, float] = field(default_factory=dict)  # "mass.box" -> the world's factor
    # [T] the anytime planner's samples per mode and plan steps (planner.budget), None without
    samples: np.ndarray | None = None
    horizon: np.ndarray | None = None
    # a team's (robots:): the first robot is ``robot``, the others' positions by name
    robot_name: str = "robot"
    others: dict[str, np.ndarray] = field(default_factory=dict)


def cos_rog(robot: np.ndarray, obj: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """cos(theta_ROG) of paper Eq. 16 in the plane, per row; NaN where a distance is zero."""
    a = select_axes(robot - obj, "xy")
    b = select_axes(goal - obj, "xy")
    norm = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, np.sum(a * b, axis=-1) / norm, np.nan)


def planar_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| in the plane, per row."""
    return np.linalg.norm(select_axes(a - b, "xy"), axis=-1)


def episode_series(scenario: Scenario, records: list[dict]) -> EpisodeSeries:
    """Replay a log's steps and track the robot, the object and the goal."""
    pair = scenario.metrics.position
    if pair is None:
        raise ConfigError(
            scenario.source,
            "metrics.position",
            "nothing to plot: no position metric and no 'near' success predicate",
            expected="metrics: {position: {a: OBJECT, b: GOAL}}",
        )
    steps = log_reader.steps(records)
    if not steps:
        raise ValueError("the episode log has no steps (the episode never started)")
    model = compile_model(scenario)
    frames = {
        "robot": resolve_frame(scenario, model, "robot", "robot"),
        "goal": resolve_frame(scenario, model, pair.b, "metrics.position.b"),
    }
    team = {m.name: m.robot.spec.frame for m in scenario.team}  # the first one is "robot"
    for name, frame in list(team.items())[1:]:
        frames[f"robot {name}"] = resolve_frame(scenario, model, frame, "robots")
    is_robot = pair.a in ("robot", next(iter(team.values()), "robot"))
    if not is_robot:
        frames["obj"] = resolve_frame(scenario, model, pair.a, "metrics.position.a")
    tracks = frame_tracks(model, steps, frames)
    actions = [
        (float(r["time"]), r["action"])
        for r in records
        if r.get("kind") == "event" and r.get("what") == "action"
    ]
    truth = log_reader.faults(records).get("faults_mismatch") or {}
    return EpisodeSeries(
        name=scenario.name,
        time=np.array([s["time"] for s in steps]),
        robot=tracks["robot"],
        obj=None if is_robot else tracks["obj"],
        goal=tracks["goal"] + np.asarray(pair.offset),
        object_name=pair.a,
        goal_name=pair.b,
        actions=actions,
        arena=scenario.world.arena.half_size if scenario.world.arena else None,
        model=model_estimates(steps),
        truth={f"{k}.{n}": float(v) for k, names in truth.items() for n, v in names.items()},
        samples=budget_series(steps, "samples"),
        horizon=budget_series(steps, "horizon"),
        robot_name=next(iter(team), "robot"),
        others={name: tracks[f"robot {name}"] for name in list(team)[1:]},
    )


def budget_series(steps: list[dict], key: str) -> np.ndarray | None:
    """``[T]`` the anytime planner's ``key`` (``samples`` per mode, or the plan's ``horizon``
    steps) for the command each step played (NaN before the first); None without a budget."""
    if not any(key in s for s in steps):
        return None
    return np.array([float(s.get(key, np.nan)) for s in steps])


def model_estimates(steps: list[dict]) -> dict[str, np.ndarray]:
    """``"KIND.NAME" -> [T]``: the identified model each step logged (its ``model``, e.g.
    ``{"mass.box": 1.4, "gain.vel_x": 0.9}``), NaN in steps without it."""
    labels = sorted({label for s in steps for label in s.get("model") or {}})
    return {
        label: np.array([(s.get("model") or {}).get(label, np.nan) for s in steps], float)
        for label in labels
    }


def plot_episode(series: EpisodeSeries, out: Path, title: str = "") -> Path:
    """One figure, three panels as in Figs. A.3-A.5 (two without an object); returns its path."""
    from matplotlib.figure import Figure

    panels = (2 if series.obj is None else 3) + bool(series.model) + (series.samples is not None)
    fig = Figure(figsize=(5.2 * panels, 4.4), layout="constrained")
    axes = fig.subplots(1, panels)
    fig.suptitle(title or series.name)
    _draw_trajectories(axes[0], series)
    _draw_distances(axes[1], series)
    if series.obj is not None:
        _draw_angle(axes[2], series)
    if series.model:
        _draw_model(axes[-1 - (series.samples is not None)], series)
    if series.samples is not None:
        _draw_samples(axes[-1], series)
    _mark_actions(axes[1:], series.actions)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out


def _draw_trajectories(ax, series: EpisodeSeries) -> None:
    """The object's and the robot's paths in the plane from their start (o), and the goal."""
    if series.obj is not None:
        ax.plot(series.obj[:, 0], series.obj[:, 1], color=OBJECT, label=series.object_name)
        ax.plot(*series.obj[0, :2], "o", color=OBJECT)
    ax.plot(series.robot[:, 0], series.robot[:, 1], color=ROBOT, label=series.robot_name)
    ax.plot(*series.robot[0, :2], "o", color=ROBOT)
    for name, track in series.others.items():  # a team's other robots
        (line,) = ax.plot(track[:, 0], track[:, 1], label=name)
        ax.plot(*track[0, :2], "o", color=line.get_color())
    ax.plot(*series.goal[-1, :2], "*", color=GOAL, markersize=14, label=series.goal_name)
    if series.arena:
        ax.set_xlim(-series.arena, series.arena)
        ax.set_ylim(-series.arena, series.arena)
    ax.set_aspect("equal")
    ax.set(xlabel="x [m]", ylabel="y [m]", title="trajectories (o: start)")
    ax.legend(loc="best", fontsize="small")


def _draw_distances(ax, series: EpisodeSeries) -> None:
    """Robot-object and object-goal distances over time (robot-goal without an object)."""
    tracked = series.robot if series.obj is None else series.obj
    if series.obj is not None:
        ax.plot(
            series.time,
            planar_distance(series.robot, series.obj),
            color=ROBOT_OBJECT,
            label=f"robot-{series.object_name}",
        )
    ax.plot(
        series.time,
        planar_distance(tracked, series.goal),
        color=OBJECT_GOAL,
        label=f"{series.object_name if series.obj is not None else series.robot_name}-"
        f"{series.goal_name}",
    )
    ax.set(xlabel="time [s]", ylabel="distance [m]", title="distances")
    ax.legend(loc="best", fontsize="small")


def _draw_angle(ax, series: EpisodeSeries) -> None:
    """cos of the robot-object-goal angle over time (paper Eq. 16)."""
    ax.plot(series.time, cos_rog(series.robot, series.obj, series.goal), color="black")
    ax.axhline(0.0, color="grey", linewidth=0.5)
    ax.set_ylim(-1.05, 1.05)
    ax.set(
        xlabel="time [s]",
        ylabel=r"cos $\theta_{ROG}$",
        title="robot-object-goal angle (-1: pushing, 1: pulling)",
    )


def _draw_model(ax, series: EpisodeSeries) -> None:
    """Each factor the planner identified over time, dashed at the world's true one."""
    for i, (label, values) in enumerate(series.model.items()):
        colour = f"C{i % 10}"
        ax.plot(series.time, values, color=colour, label=label)
        if label in series.truth:
            ax.axhline(series.truth[label], color=colour, linestyle="--", linewidth=0.8)
    ax.axhline(1.0, color="grey", linewidth=0.5)
    ax.set(
        xlabel="time [s]",
        ylabel="factor of the nominal model",
        title="identified model (dashed: the world's)",
    )
    ax.legend(loc="best", fontsize="small")


def _draw_samples(ax, series: EpisodeSeries) -> None:
    """The anytime planner's samples per mode over time, and on the right axis its plan's
    steps: where it shed them to keep its budget (planner.budget) and took them back."""
    ax.step(series.time, series.samples, where="post", color="C3")
    ax.set(
        xlabel="time [s]",
        ylabel="samples per mode",
        title="samples and horizon under the budget",
        ylim=(0, np.nanmax(series.samples) * 1.1),
    )
    if series.horizon is not None and np.isfinite(series.horizon).any():
        steps = ax.twinx()
        steps.step(series.time, series.horizon, where="post", color="C0", linestyle="--")
        steps.set(ylabel="horizon steps", ylim=(0, np.nanmax(series.horizon) * 1.1))


def _mark_actions(axes, actions: list[tuple[float, str]]) -> None:
    """A dotted line where the planner's action changed, named, on every panel over time."""
    for ax in axes:
        for t, action in actions:
            ax.axvline(t, color="grey", linestyle=":", linewidth=0.8)
            ax.annotate(
                action,
                (t, 1.0),
                xycoords=("data", "axes fraction"),
                rotation=90,
                va="top",
                ha="right",
                fontsize="x-small",
                color="grey",
            )
