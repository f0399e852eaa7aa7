"""One benchmark case measured: a scenario's control loop (:class:`planner_client.controller.
Controller`) closed loop in-process against bare ``mujoco.rollout`` calls replaying its samples
(``scripts/benchmark.py`` is the command, and its docstring says what each ratio means). Apart
from the command so that it refuses a wrong option before it imports torch and the planner."""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Iterator

import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout

from planner_client.build import build_controller
from planner_client.controller import Controller
from planner_client.maps import map_config
from planner_client.model_state import get_full_state
from planner_client.motion import MotionPlanner
from planner_client.problem import apply_planning_model, planner_scenario, tune_planning_model
from server.sensors import RangeSensors
from shared import protocol as P
from shared.scenario import Scenario
from shared.scene import build_spec, compile_model, initial_data


def _own_model(scenario: Scenario, timestep: float) -> mujoco.MjModel:
    """The planner's own model (its options, with steps of ``timestep``) without the sensors
    its costs read: without the perceived objects, as the planner builds it."""
    own_spec = build_spec(planner_scenario(scenario))
    own_spec.option.timestep = timestep
    apply_planning_model(own_spec, scenario.planner.model, scenario.source)
    own = compile_model(scenario, own_spec)
    tune_planning_model(own, scenario.planner.model)
    return own


def _variant_copies(planner: MotionPlanner) -> int:
    """How many times the planner rolls out each sample: with planner.model.variants' spread:
    all, every sample rolls out in every variant."""
    return (
        planner.variants.cfg.count
        if planner.variants is not None and planner.variants.cfg.spread == "all"
        else 1
    )


@dataclasses.dataclass
class _Sensing:
    """The scenario's range sensors read off the world the controller drives: the world's
    full model (with the objects only the sensors show; they stand still here) posed as the
    planner's copy of the world, so the map is fed as a lock-step world feeds it."""

    world: mujoco.MjModel
    data: mujoco.MjData
    sensors: RangeSensors

    @classmethod
    def of(cls, scenario: Scenario) -> _Sensing | None:
        """None for a scenario without sensors."""
        if not scenario.sensors:
            return None
        world = compile_model(scenario)
        return cls(world, initial_data(scenario, world), RangeSensors(scenario, world))

    def scans(self, data: mujoco.MjData) -> list:
        """The readings due at ``data``'s time (the planner's model: the same joints, as its
        perceived objects are fixed)."""
        self.data.qpos[:], self.data.time = data.qpos, data.time
        mujoco.mj_kinematics(self.world, self.data)
        self.sensors.update(self.world, self.data)
        return self.sensors.take()


class _Replayed:
    """A rollout backend whose rollouts return a copy of its first one's sensordata (a new
    one when the samples or horizon change: the task layer may switch modes); all else is the
    wrapped backend's (:meth:`_Bench.replayed_split`)."""

    def __init__(self, engine):
        self._engine = engine
        self._kept: torch.Tensor | None = None

    def sensors(self, x0, control, mocap_path=None) -> torch.Tensor:
        """The kept sensordata ``[S, T, nsensordata]``, rolled out for real when ``control``'s
        samples or horizon are new."""
        if self._kept is None or self._kept.shape[:2] != control.shape[:2]:
            self._kept = self._engine.sensors(x0, control, mocap_path).clone()
        return self._kept

    def __getattr__(self, name: str):
        return getattr(self._engine, name)


def _lockstep_state(data: mujoco.MjData, seq: int) -> P.State:
    """The state of ``data`` as a lock-step world publishes it."""
    return P.State(
        session="bench",
        seq=seq,
        time=float(data.time),
        qpos=data.qpos.copy(),
        qvel=data.qvel.copy(),
        act=data.act.copy(),
        mocap_pos=data.mocap_pos.copy(),
        mocap_quat=data.mocap_quat.copy(),
    )


@dataclasses.dataclass
class _Bench:
    """The controller in closed loop and the bare rollouts that replay its recent iterations,
    each timed in blocks of its own (see :func:`measure`)."""

    controller: Controller
    planner: MotionPlanner
    model: mujoco.MjModel  # the planner's
    data: mujoco.MjData  # the world the controller drives, in the planner's model
    world: mujoco.MjModel
    own: mujoco.MjModel  # the planner's own model without sensors (_own_model)
    hold: int  # world steps per planned step
    horizon: int
    copies: int  # rollouts of each sample (_variant_copies)
    block: int  # timed calls per block
    world_data: list[mujoco.MjData]  # one per rollout thread
    own_data: list[mujoco.MjData]
    sensing: _Sensing | None
    work: list[tuple[np.ndarray, np.ndarray]] = dataclasses.field(default_factory=list)
    times: dict[str, list[float]] = dataclasses.field(
        default_factory=lambda: {"plan": [], "world": [], "own": [], "sensors": []}
    )
    map_times: list[float] = dataclasses.field(default_factory=list)  # s per map update
    seq: Iterator[int] = dataclasses.field(default_factory=itertools.count)
    replayed: Iterator[int] = dataclasses.field(default_factory=itertools.count)

    @classmethod
    def around(cls, scenario: Scenario, controller: Controller, nthread: int, block: int) -> _Bench:
        """The harness of ``controller``, its world at the scenario's start and ``nthread``
        rollout threads, timing ``block`` calls per block."""
        planner = controller.motion
        model = planner.problem.model
        data = initial_data(scenario, model)  # the scenario's start pose (the Panda's ready pose)
        world = compile_model(scenario)
        own = _own_model(scenario, model.opt.timestep)
        return cls(
            controller=controller,
            planner=planner,
            model=model,
            data=data,
            world=world,
            own=own,
            hold=round(model.opt.timestep / world.opt.timestep),
            horizon=scenario.planner.horizon,
            copies=_variant_copies(planner),
            block=block,
            world_data=[mujoco.MjData(world) for _ in range(nthread)],
            own_data=[mujoco.MjData(own) for _ in range(nthread)],
            sensing=_Sensing.of(scenario),
        )

    def run_round(self, pool: mj_rollout.Rollout) -> None:
        """One block of each in turn: planner iterations, then the replays on the world's
        model, on the planner's own, and on it with its sensors."""
        self._timed("plan", self._plan_step)
        self._timed("world", self._world_rollout, pool)
        self._timed("own", self._own_rollout, pool)
        self._timed("sensors", self._sensor_rollout)

    def medians(self) -> dict[str, float]:
        """The median seconds of each kind of call."""
        return {k: float(np.median(v)) for k, v in self.times.items()}

    def _timed(self, key: str, fn: Callable[..., float | None], *args) -> None:
        for i in range(self.block + 3):
            t = time.perf_counter()
            took = fn(*args)
            if i >= 3:  # the first calls of a block warm caches and threads
                self.times[key].append(took if took is not None else time.perf_counter() - t)

    def _plan_step(self) -> float:
        """One controller step, timed by itself (the command's ``plan_time``): the world's
        step and the copies kept for the replays around it are the harness's work, not the
        planner's (60 µs of navigation's). The map is updated before it, timed apart: a
        real-time planner updates it beside its iterations (planner_client/perception)."""
        self._update_map()
        cmd = self.controller.step(_lockstep_state(self.data, next(self.seq)))
        # the start state the iteration rolled out from: the mirror's (no delays: no prediction)
        x0 = get_full_state(self.model, self.controller.mirror.data).copy()
        self.work.append((x0, self.planner.last_samples.copy()))
        del self.work[: -self.block]
        self.data.ctrl[:] = cmd.ctrl
        mujoco.mj_step(self.model, self.data)
        return cmd.plan_time

    def replayed_split(self, steps: int) -> dict[str, float]:
        """Median ms per phase of ``steps`` more iterations whose rollout returns a copy of a
        real one's sensordata: what the rest of an iteration costs when no rollout has just
        run on every core and evicted its code and data from the caches (its floor, whatever
        the rollout's speed). Run last: their plans come from stale sensors."""
        engine = self.planner.engine
        self.planner.engine = _Replayed(engine)
        try:
            for i in range(steps + 3):
                self._plan_step()
                if i == 2:  # the first replay rolls out for real
                    self.planner.phases.keep()
        finally:
            self.planner.engine = engine
        return self.planner.phases.median_ms()

    def _update_map(self) -> None:
        """Feed the map the scans due now and update it, as a lock-step controller does at a
        state that brings scans; its time goes to ``map_times``."""
        if self.sensing is None or self.controller.map is None:
            return
        scans = self.sensing.scans(self.data)
        if scans:
            self.controller.map.submit(scans, self.data)  # the scene: the self-filter
            t = time.perf_counter()
            self.controller.map.update_now()
            self.map_times.append(time.perf_counter() - t)

    def _world_rollout(self, pool: mj_rollout.Rollout) -> None:
        # sensors add no state, so the planner's x0 is a valid world state
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        pool.rollout(
            self.world,
            self.world_data,
            x0[None],
            np.repeat(ctrl, self.hold, axis=1),
            nstep=self.horizon * self.hold,
        )

    def _own_rollout(self, pool: mj_rollout.Rollout) -> None:
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        pool.rollout(self.own, self.own_data, x0[None], ctrl, nstep=self.horizon)

    def _sensor_rollout(self) -> None:
        x0, ctrl = self.work[next(self.replayed) % len(self.work)]
        ctrl = np.tile(ctrl, (self.copies, 1, 1))
        self.planner.engine.sensors(x0, torch.from_numpy(ctrl).to(self.planner.device))


def measure(
    scenario: Scenario,
    iterations: int,
    nthread: int,
    rounds: int,
    backend: str = "mujoco",
    device: str = "cuda:0",
) -> dict:
    """Median planner iteration and median bare rollouts, measured in alternating blocks.

    The controller runs closed loop (its command applied to its own copy of the world, a state
    per step as a lock-step world publishes it). The bare rollouts
    replay exactly the planner's own work: the [S, T] samples and start states of its last
    iterations, on the world model over the same seconds (no planner sensors), on the planner's
    own model without sensors, and on it with the sensors its costs read. Blocks alternate
    ``rounds`` times (``scripts/benchmark.py``: 20, of ten iterations at its default 200), so
    that background load and a virtual machine's drifting speed hit all four alike; each pool is
    used only in its own block so idle threads never compete.
    """
    controller = build_controller(scenario, nthread, backend=backend, device=device)
    bench = _Bench.around(scenario, controller, nthread, block=max(1, iterations // rounds))
    controller.begin("lockstep", bench.model.opt.timestep)
    try:
        with mj_rollout.Rollout(nthread=nthread) as pool:
            for i in range(rounds):
                bench.run_round(pool)
                if i == 0:  # the split over warm iterations only, as the medians
                    bench.planner.phases.keep()
        phases = bench.planner.phases.median_ms()
        replayed = bench.replayed_split(max(rounds, iterations // 4))
    finally:
        controller.close()
    return _row(scenario, bench, nthread, backend, device, phases, replayed)


def _row(
    scenario: Scenario,
    bench: _Bench,
    nthread: int,
    backend: str,
    device: str,
    phases: dict[str, float],
    replayed: dict[str, float],
) -> dict:
    """One case's result: what ran, the median times and their ratios, and the split of an
    iteration (``phases``: ms per phase) as measured and with its rollout replayed."""
    med = bench.medians()
    return {
        "scenario": scenario.name,
        "samples": bench.planner.mppi.num_samples,
        "horizon": bench.horizon,
        "hz": round(1.0 / med["plan"], 2),
        "planning_step": float(bench.model.opt.timestep),
        "world_step": float(bench.world.opt.timestep),
        "planning_model": scenario.planner.model.as_dict(),
        "ratio_to_rollout": round(med["plan"] / med["world"], 3),
        "ratio_to_own_rollout": round(med["plan"] / med["own"], 3),
        "ratio_to_sensor_rollout": round(med["plan"] / med["sensors"], 3),
        "iteration_ms": round(med["plan"] * 1e3, 3),
        "rollout_ms": round(med["world"] * 1e3, 3),
        "own_rollout_ms": round(med["own"] * 1e3, 3),
        "sensor_rollout_ms": round(med["sensors"] * 1e3, 3),
        "threads": nthread,
        "backend": backend,
        "device": device if backend == "warp" else "cpu",
        "phases_ms": {k: round(v, 4) for k, v in phases.items()},
        "phases_replayed_ms": {k: round(v, 4) for k, v in replayed.items()},
        **_map_figures(scenario, bench),
    }


def _map_figures(scenario: Scenario, bench: _Bench) -> dict:
    """A scenario with sensors: the map's median update (fusing the scans due and its signed
    distance field), the rate it is updated at (the slower of the fastest sensor and
    ``planner.map.rate``) and the share of one core that takes."""
    if not bench.map_times:
        return {}
    update = float(np.median(bench.map_times))
    rate = min(max(s.rate for s in scenario.sensors), map_config(scenario).rate_hz)
    return {
        "map_update_ms": round(update * 1e3, 3),
        "map_rate_hz": rate,
        "map_core_share": round(update * rate, 4),
    }
