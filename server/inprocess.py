"""Run a whole episode in one process: the world and a planner, no ZeroMQ.

What ``m3p2i run NAME --seed S`` does in lock-step with two processes, done with function calls:
the world publishes state ``seq``, the planner's control loop answers it (thesis Alg. 1), the
world plays the command's plan for ``plan_every`` steps (its knot for each step's world time,
the safe control past its end), and publishes the next state. The episode, its log and its
summary are the two-process run's step for step, bit for bit (tests/server/test_inprocess.py checks
it); only the session id, the wall-clock times and the planning times differ.

The world never imports the planner (docs/architecture.md, import rules): the caller hands it
the planner's factory, :func:`planner_client.build.build_controller` (``build_controller``
below, imported from there by the caller). One call for a whole episode::

    from server.inprocess import run_episode

    result = run_episode("navigation", build_controller, seed=0)
    result.status, result.summary["time"], result.log_path

The building blocks, for a notebook, a learning pipeline or a robot's own loop::

    from server.inprocess import build_episode

    controller = build_controller("navigation", seed=0)      # planner_client.controller
    episode = build_episode("navigation", seed=0)             # server.episode
    controller.begin("lockstep", episode.dt)
    state = episode.publish()
    while not controller.over(state):
        command = controller.step(state)       # P.Command: ctrl now, and the dated plan
        episode.play(command)                  # one world step under it
        state = episode.publish()
    outcome = episode.finish()
    controller.close()
    episode.close()
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from server.episode import Episode
from server.evaluation.log_reader import read_log, summary
from server.interface import Outcome, World
from server.options import load_faults
from server.world import SimWorld
from shared import protocol as P
from shared.scenario import Scenario, load_scenario
from shared.scenario.faults import FaultConfig

__all__ = ["ControlLoop", "EpisodeResult", "build_episode", "drive", "run_episode"]


class ControlLoop(Protocol):
    """What the world asks of a planner's control loop in one process: the methods of
    :class:`planner_client.controller.Controller` that :func:`drive` calls."""

    stats: Any

    def begin(self, mode: str, dt: float) -> None: ...

    def check_layout(self, state: P.State) -> None: ...

    def over(self, state: P.State) -> bool: ...

    def step(self, state: P.State) -> P.Command | None: ...

    def close(self) -> None: ...


ControlLoopFactory = Callable[..., ControlLoop]
"""Builds the planner of a scenario, called as ``factory(scenario, seed=seed)``:
:func:`planner_client.build.build_controller`, or a ``functools.partial`` of it with
``threads``, ``backend`` or ``device`` set."""

OnStep = Callable[[P.State, P.Command], None]
"""Called with each state and the command answering it, once the world has played it."""


@dataclass(frozen=True)
class EpisodeResult:
    """How an in-process episode ended: the world's outcome (measures with ``planner_hz``),
    the log's summary record, where the log is, and what the controller did."""

    outcome: Outcome
    summary: dict
    log_path: Path
    stats: Any  # the planner's own statistics (a Controller's LoopStats; a team's: by robot)

    @property
    def status(self) -> str:
        """success | timeout | stopped."""
        return self.outcome.status

    @property
    def success(self) -> bool:
        return self.outcome.status == "success"


def _scenario(scenario: str | Path | Scenario) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


def build_episode(
    scenario: str | Path | Scenario,
    seed: int = 0,
    log_path: str | Path | None = None,
    faults: FaultConfig | str | None = None,
    world: type[World] = SimWorld,
) -> Episode:
    """The world of ``scenario`` from ``seed``'s start as ``m3p2i-server --seed seed`` builds
    it in lock-step, logging to ``log_path`` (default: ``episode.jsonl`` in a new temporary
    folder). ``faults``: a profile name, a file or a config of the faults the world shows
    (default: the scenario's ``faults:``); ``world``: a :class:`server.interface.World`
    class (default: the simulation)."""
    if log_path is None:
        log_path = Path(tempfile.mkdtemp(prefix="m3p2i-")) / "episode.jsonl"
    if isinstance(faults, str):
        faults = load_faults(faults)
    return Episode(_scenario(scenario), seed, Path(log_path), world, faults)


def _published(episode: Episode) -> P.State:
    """The episode's current state as a lock-step planner gets it: a state the world's link
    loses is published again (the loss costs a two-process world wall time, not world time)."""
    state = episode.publish()
    return state if state is not None else episode.publish()


def drive(
    episode: Episode,
    controller: ControlLoop | list[ControlLoop],
    plan_every: int = 1,
    max_steps: int | None = None,
    on_step: OnStep | None = None,
) -> Outcome:
    """Lock-step: ``controller`` answers each state of ``episode`` and the world plays each
    command for ``plan_every`` steps, until the episode ends (or ``max_steps`` world steps:
    then it is ``stopped``). A team's world: a list, one controller per robot in the team's
    order, each answering every state (``on_step`` then sees the list of commands). The
    episode is always finished (its summary written, the robots stopped), whatever raised;
    returns its outcome."""
    loops = controller if isinstance(controller, list) else [controller]
    try:
        for loop in loops:
            loop.begin("lockstep", episode.dt)
        state = _published(episode)
        for loop in loops:
            loop.check_layout(state)
        while not any(loop.over(state) for loop in loops):
            commands = [loop.step(state) for loop in loops]
            if None in commands:
                raise ValueError(
                    f"state {state.seq} does not fit the planner's model (logged above)"
                )
            command = commands if isinstance(controller, list) else commands[0]
            episode.play(command, plan_every)
            if on_step is not None:
                on_step(state, command)
            if max_steps is not None and episode.steps >= max_steps and episode.running:
                episode.abort()
            state = _published(episode)
    finally:
        outcome = episode.finish()
    return outcome


def run_episode(
    scenario: str | Path | Scenario,
    planner: ControlLoopFactory,
    seed: int = 0,
    log_path: str | Path | None = None,
    plan_every: int = 1,
    faults: FaultConfig | str | None = None,
    max_steps: int | None = None,
    on_step: OnStep | None = None,
) -> EpisodeResult:
    """One lock-step episode of ``scenario`` in this process: the same steps, log and summary
    as ``m3p2i run SCENARIO --seed seed --plan-every plan_every [--faults ...]`` (world
    and planner seeded with ``seed``; ``planner(scenario, seed=seed)`` builds the planner, e.g.
    :func:`planner_client.build.build_controller`). ``max_steps`` stops the episode after that
    many world steps; ``on_step`` sees each state and the command answering it."""
    sc = _scenario(scenario)
    # a team's scenario: a controller per robot, each planning from its robot's view
    loops = [planner(view, seed=seed) for view in sc.members.values()] or [planner(sc, seed=seed)]
    try:
        episode = build_episode(sc, seed, log_path, faults)
        try:
            outcome = drive(episode, loops if sc.team else loops[0], plan_every, max_steps, on_step)
        finally:
            episode.close()
    finally:
        for loop in loops:
            loop.close()
    stats = {name: loop.stats for name, loop in zip(sc.members, loops)} or loops[0].stats
    return EpisodeResult(
        outcome, summary(read_log(episode.log.path)) or {}, episode.log.path, stats
    )
