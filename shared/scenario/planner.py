"""The ``planner`` section: samples, horizon, rollout backend, timing and delays, and its
subsections (``model``, ``tracking``, ``delays``, ``mppi``)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from shared.config import (
    Section,
    flag,
    non_negative,
    one_of,
    positive,
    positive_int,
    string_list,
)
from shared.scenario.common import STEP_SECONDS, step_seconds
from shared.scenario.model import PlanningModel, read_planning_model
from shared.scenario.mppi import MppiSettings, read_mppi
from shared.scenario.tracking import TrackingConfig, read_tracking
from shared.scenario.variants import MAX_VARIANT_ROLLOUTS
from shared.scenario.world import WorldConfig

# Rollout backends (planner.backend): "mujoco" is mujoco.rollout's thread pool on the CPU, the
# default; "warp" is MuJoCo Warp (the m3p2i[gpu] extra) on planner.device.
ROLLOUT_BACKENDS = ("mujoco", "warp")


def rollout_device(value: Any) -> str:
    """Converter for a warp device name: ``cpu``, ``cuda`` or ``cuda:N``."""
    if not isinstance(value, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", value):
        raise ValueError("must be cpu, cuda or cuda:N")
    return value


@dataclass(frozen=True)
class DelayConfig:
    """``planner.delays``: delays of the robot that no message shows, declared so the planner
    plans for the state its plan will meet (docs/faults.md, "Delay compensation").
    ``actuation_ms``: from a command reaching the world to the actuators acting on it;
    ``state_ms``: from a measurement to its state being published (a state's ``time`` is
    its measurement's). ``measure``: measure them online instead, the state delay from
    ``state.lag``, the actuation delay (up to ``max_ms``) from the robot's response; a declared
    value stands until the estimate has one."""

    actuation_ms: float = 0.0
    state_ms: float = 0.0
    measure: bool = False  # measure both online (planner_client/delay_estimate.py)
    max_ms: float = 300.0  # the longest actuation delay the estimate considers

    @property
    def active(self) -> bool:
        return bool(self.actuation_ms or self.state_ms or self.measure)


@dataclass(frozen=True)
class PlannerConfig:
    """Motion-planner parameters."""

    samples: int = 200
    horizon: int = 15
    mppi: MppiSettings = field(default_factory=MppiSettings)  # M3P2I's own keys
    threads: int = 0  # rollout threads; 0 = one per core
    aip_period: float = 0.2  # simulated seconds between active-inference ticks
    # seconds an observed change of a task factor must persist before the task layer acts on
    # it, per factor ("*": the others); 0 acts on every observation (planner_client.task)
    confirm: dict[str, float | dict[str, float]] = field(default_factory=dict)
    timestep: float | None = None  # planning step (s), a multiple of the world's; None = its
    backend: str = "mujoco"  # rollouts: "mujoco" (mujoco.rollout pool) or "warp" (MJWarp)
    device: str = "cuda:0"  # the warp backend's device: "cpu" or "cuda[:N]"
    nconmax: int | None = None  # warp: contacts per world; None = estimated at start
    njmax: int | None = None  # warp: constraint rows per world; None = estimated
    model: PlanningModel = field(default_factory=PlanningModel)  # the rollout model's own options
    # the mirror's filters for the free bodies
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    delays: DelayConfig = DelayConfig()  # the robot's unseen delays, compensated by prediction
    map: dict = field(default_factory=dict)  # the lidar map's keys, read by planner_client.maps
    budget: dict = field(default_factory=dict)  # the anytime planner's: planner_client.budget
    shared_plans: bool = True  # a team's: roll the others out along their plans (team.py)
    passes_through: tuple[str, ...] = ()  # a team's: robots that give way to this one (team.py)

    def step(self, world: WorldConfig) -> float:
        """Seconds per planned control step: ``timestep``, or the world's."""
        return self.timestep or world.timestep


def read_planner(s: Section) -> PlannerConfig:
    samples = s.opt("samples", 200, positive_int)
    horizon = s.opt("horizon", 15, positive_int)
    cfg = PlannerConfig(
        samples=samples,
        horizon=horizon,
        mppi=read_mppi(s.section("mppi", required=False), horizon, samples),
        threads=s.opt("threads", 0, int),
        aip_period=s.opt("aip_period", 0.2, positive, "simulated seconds"),
        confirm=s.opt(
            "confirm",
            {},
            _confirm_times,
            "seconds >= 0, or a map {factor: seconds or {state: seconds}, '*': seconds}",
        ),
        timestep=s.opt(
            "timestep", None, step_seconds, f"{STEP_SECONDS}, a multiple of world.timestep"
        ),
        backend=s.opt("backend", "mujoco", one_of(ROLLOUT_BACKENDS)),
        device=s.opt("device", "cuda:0", rollout_device, "cpu, cuda or cuda:N"),
        nconmax=s.opt("nconmax", None, positive_int, "contacts per world"),
        njmax=s.opt("njmax", None, positive_int, "constraint rows per world"),
        model=read_planning_model(s.section("model", required=False)),
        tracking=read_tracking(s.section(s.renamed("estimate", "tracking"), required=False)),
        delays=_delays(s.section("delays", required=False)),
        map=s.opt("map", {}, dict, "{resolution: m, rate: Hz}"),
        budget=s.opt("budget", {}, lambda v: {} if v is None else {**v}, "{rate: Hz, ...} or null"),
        shared_plans=s.opt("shared_plans", True, flag),
        passes_through=s.opt("passes_through", (), string_list, "a list of the team's robots"),
    )
    s.done()
    _check_variants(s, cfg)
    return cfg


def _check_variants(s: Section, cfg: PlannerConfig) -> None:
    """``planner.model.variants`` against the rest of ``planner``: MJWarp rolls out one model
    for all its worlds, and a split needs a sample per variant in every mode."""
    v = cfg.model.variants
    if v is None:
        return
    path = "model.variants"
    if cfg.backend != "mujoco":
        raise s.error(
            path,
            f"the {cfg.backend} backend rolls out one model for all samples",
            v.as_dict(),
            "backend: mujoco (mujoco.rollout takes a model per rollout), or no variants",
        )
    if v.spread == "all" and v.count * cfg.samples > MAX_VARIANT_ROLLOUTS:
        raise s.error(
            f"{path}.count",
            f"{v.count} variants x planner.samples = {cfg.samples}: "
            f"{v.count * cfg.samples:,} rollouts per mode and iteration",
            v.count,
            f"count x samples <= {MAX_VARIANT_ROLLOUTS:,} with spread: all",
        )
    if v.spread == "split" and v.count > cfg.samples:
        raise s.error(
            f"{path}.count",
            f"{v.count} variants split over planner.samples = {cfg.samples} per mode",
            v.count,
            f"count <= {cfg.samples} (or spread: all)",
        )


def _delays(s: Section) -> DelayConfig:
    cfg = DelayConfig(
        actuation_ms=s.opt("actuation_ms", 0.0, non_negative, "milliseconds >= 0"),
        state_ms=s.opt("state_ms", 0.0, non_negative, "milliseconds >= 0"),
        measure=s.opt(s.renamed("estimate", "measure"), False, flag, "true or false"),
        max_ms=s.opt("max_ms", 300.0, positive, "milliseconds > 0"),
    )
    s.done()
    return cfg


def _confirm_times(value: Any) -> dict[str, float | dict[str, float]]:
    """``seconds``, or ``{factor: seconds | {state: seconds}, '*': seconds}``: a factor's
    mapping gives the time a change *to* each listed state must persist (unlisted: at once),
    so one direction can be quick and the other slow (hysteresis)."""
    if not isinstance(value, dict):
        return {"*": non_negative(value)}
    if not all(isinstance(k, str) for k in value):
        raise ValueError("wrong type")
    out: dict[str, float | dict[str, float]] = {}
    for k, v in value.items():
        if isinstance(v, dict) and k != "*":
            if not all(isinstance(state, str) for state in v):
                raise ValueError("wrong type")
            out[k] = {state: non_negative(t) for state, t in v.items()}
        else:
            out[k] = non_negative(v)
    return out
