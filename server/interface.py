"""The world interface: everything the server (:class:`server.episode.Episode` and
:class:`server.app.WorldServer`) needs from a world.

The server owns the episode (sessions, the episode log and its metrics, plan playing, control
ops) and the network side (handshake, the lock-step or real-time loop, the stale-command
watchdog); a world only applies controls and reports its state.
:class:`server.world.SimWorld` (MuJoCo) is one implementation; :class:`server.bridge.Bridge` is
the base of a world the server does not simulate (a robot, another simulator);
``m3p2i-server --world package.module:Class`` serves any subclass of :class:`World`
(docs/bridge.md).

How the server uses a world, per episode:

1. ``cls(scenario, seed)`` builds it (a hardware bridge connects here); the scenario's model is
   compiled by :class:`World` (``self.model``): states are in its coordinates, and the episode
   log's header and metrics need it.
2. ``reset()`` once: the start of the episode (time 0, status ``running``).
3. ``state()`` for every published state; ``step(ctrl)`` applies a control for one period
   ``dt``. Lock-step: one step per command. Real-time: the server's rate loop keeps the time,
   calling ``step`` every ``dt`` of wall-clock time, so ``step`` must return well within the
   period (send the command, read the newest measurement: never sleep out the period).
   Between steps a control holds (zero-order hold). ``scans()`` once per published state: the
   sensors' readings since the previous one, which that state carries. The episode log records
   ``true_state()`` (by default ``state()``; :class:`server.faults.FaultyWorld`'s noisy, late
   ``state()`` is only what the planner is sent), and a state for which ``drop_state()`` is
   true is lost.
4. ``status`` is read after each step (``running``, ``success``, ``timeout``; the server sets
   ``stopped``); ``events`` are logged and cleared by the server; ``extras`` are published.
5. ``stop()`` when the episode ends, on pause, Ctrl-C or SIGTERM: hold the robot still now.
6. ``close()`` before the next episode's world is built, and when the server exits.
"""

from __future__ import annotations

import importlib
import inspect
import os
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass

import mujoco
import numpy as np

from shared.scans import Scan
from shared.scenario import Scenario
from shared.scene import compile_model


@dataclass
class WorldState:
    """The world's full state in the scenario model's coordinates (docs/protocol.md ``state``):
    ``qpos [nq]``, ``qvel [nv]``, ``act [na]``, ``mocap_pos [nmocap, 3]``, ``mocap_quat
    [nmocap, 4]`` (w, x, y, z); SI units; ``time`` in world seconds since the episode began."""

    time: float
    qpos: np.ndarray
    qvel: np.ndarray
    act: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray


@dataclass
class Outcome:
    status: str  # running | success | timeout | stopped
    time: float  # world seconds
    measures: dict[str, float]


class WorldError(RuntimeError):
    """A world that cannot be built or run (a robot that does not answer, a missing
    calibration): ``m3p2i-server`` prints the message and exits with code 2, no traceback."""


class WorldLoadError(ValueError):
    """A ``--world`` value that does not name a usable :class:`World` subclass."""


class World(ABC):
    """What the server needs from a world (the module docstring says in which order).

    Attributes the server reads (set by ``__init__``; a subclass keeps them current):
        scenario: the scenario being served.
        seed: this episode's seed (a simulated world draws its randomised start from it).
        model: the scenario's compiled ``mujoco.MjModel``; ``nq``/``nu`` and the coordinates
            of every state come from it.
        robot: the robot's :class:`shared.robots.RobotSpec` (its safe control).
        status: ``running`` until ``success`` or ``timeout``; the server sets ``stopped``.
        extras: named scalars published with each state (e.g. ``battery`` in %).
        events: disturbances since the server last read them (``object``, ``pos``, ``time``);
            the server logs and clears them.
        initial: what ``reset`` drew for the start (randomised poses), for the log's header.
        data: the world's ``mujoco.MjData`` when it keeps one (what ``--window`` draws), else
            None. The server itself never reads it.
    """

    def __init__(self, scenario: Scenario, seed: int = 0):
        self.scenario = scenario
        self.seed = seed
        self.model = compile_model(scenario)
        self.robot = scenario.robot.spec
        self.status = "running"
        self.extras: dict[str, float] = {}
        self.events: list[dict] = []
        self.initial: list[dict] = []
        self.data: mujoco.MjData | None = None

    @property
    def dt(self) -> float:
        """Seconds per step: the control period, the scenario's ``world.timestep``."""
        return float(self.model.opt.timestep)

    @property
    @abstractmethod
    def time(self) -> float:
        """World seconds since the episode began (plans are dated in this clock)."""

    @property
    @abstractmethod
    def ctrl(self) -> np.ndarray:
        """The control ``[nu]`` the latest step applied (clipped), logged with each step."""

    @abstractmethod
    def reset(self) -> None:
        """Begin the episode: time 0, status ``running``, the start state ready for ``state``."""

    @abstractmethod
    def state(self) -> WorldState:
        """The current state (copies: the server keeps them while the world goes on)."""

    @abstractmethod
    def step(self, ctrl: np.ndarray) -> None:
        """Apply ``ctrl`` ``[nu]`` (actuator units; clip it to the model's ranges) for one
        period ``dt``, then update the state, ``time`` and ``status``."""

    @abstractmethod
    def outcome(self) -> Outcome:
        """Status, time and the success test's measures (e.g. the distance to the goal)."""

    def true_state(self) -> WorldState:
        """The state as it is, for the episode log and its metrics; ``state()`` is what the
        planner is sent. They differ only in a world that simulates measurement faults
        (:class:`server.faults.FaultyWorld`: noise, delay)."""
        return self.state()

    def scans(self) -> list[Scan]:
        """The readings of the scenario's ``sensors:`` measured since the last call, oldest
        first, each stamped with its measurement's world time and the sensor's pose then
        (:class:`shared.scans.Scan`): the server publishes them once, with the next state. None
        by default; :class:`server.world.SimWorld` simulates them, a bridge returns its
        lidar's and cameras' (docs/bridge.md)."""
        return []

    def drop_state(self) -> bool:
        """Whether the link loses the state about to be published (asked once per state;
        :class:`server.faults.FaultyWorld`'s ``drop_rate``). None is lost by default."""
        return False

    def safe_command(self) -> np.ndarray:
        """The control that holds the robot still (the robot's ``safe_ctrl``), its
        ``hold_ctrl`` actuators (a gripper) kept at their last command: what the server applies
        when commands go stale or a plan runs out."""
        return self.robot.safe_stop(self.ctrl)

    def stop(self) -> None:  # noqa: B027  optional hook: the default does nothing
        """Hold the robot still now: the episode ended, the world was paused or interrupted.
        A simulated world does nothing (its time stands still between steps)."""

    def move_object(self, name: str, pos, quat=None) -> dict:
        """Put scenario object ``name`` at ``pos`` (``quat`` w x y z) for the control op
        ``move``; returns the event to log. A ValueError says why not (the server answers the
        tool with it). By default a world cannot: real objects are not moved by a message."""
        raise ValueError(f"this world ({type(self).__name__}) cannot move objects")

    def close(self) -> None:  # noqa: B027  optional hook: the default does nothing
        """Release what the world holds (a robot's connection); nothing by default."""

    def clip(self, ctrl: np.ndarray) -> np.ndarray:
        """``ctrl`` clipped to the actuators' ``ctrlrange`` (a new array)."""
        lo, hi = self.model.actuator_ctrlrange.T
        return np.clip(np.asarray(ctrl, dtype=float), lo, hi)


def world_name(cls: type) -> str:
    """``package.module:Class``, the form ``--world`` takes (and the log's header records)."""
    return f"{cls.__module__}:{cls.__qualname__}"


def load_world_class(spec: str) -> type[World]:
    """The :class:`World` subclass ``spec`` names (``package.module:Class``), imported the
    usual way (installed packages, ``PYTHONPATH``, the current directory). The operator's local
    choice; never a value received over the network. :class:`WorldLoadError` says what is
    wrong with ``spec`` and what was expected."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise WorldLoadError(
            f"--world {spec!r}: expected package.module:Class (e.g. my_robot.bridge:MyBridge)"
        )
    # a console script's sys.path lacks the current directory that `python -m server` has:
    # appended, so that it never shadows an installed package
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name or module_name.startswith(f"{exc.name}."):  # not its imports
            raise WorldLoadError(
                f"--world {spec!r}: no module named {exc.name!r} (is it "
                f"installed, on PYTHONPATH or in the current directory?)"
            ) from None
        raise WorldLoadError(f"--world {spec!r}: importing {module_name} failed: {exc}") from exc
    try:
        cls = module
        for part in attr.split("."):
            cls = getattr(cls, part)
    except AttributeError:
        raise WorldLoadError(
            f"--world {spec!r}: module {module_name} ({module.__file__}) has no {attr!r}"
        ) from None
    if not (inspect.isclass(cls) and issubclass(cls, World)):
        raise WorldLoadError(
            f"--world {spec!r}: {attr} is not a subclass of "
            f"server.interface.World (server.bridge.Bridge for a robot), it is "
            f"{cls!r}"
        )
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise WorldLoadError(
            f"--world {spec!r}: {attr} leaves abstract: {missing}; implement them (docs/bridge.md)"
        )
    return cls
