"""The paper's control loop (thesis Alg. 1) for one robot: state in, dated command out.

:class:`Controller` holds everything the loop keeps between ticks and nothing of the network:
its :class:`Parts` (the motion planner (M3P2I), the task layer, the mirror of the world in the
planner's model, the attachments (welds of held objects), the guide, the model identifier),
the delay estimates and the plans already sent. One
:meth:`Controller.step` is one tick of Alg. 1:

1. mirror the received state into the planner's model (and weld what the robot holds);
2. estimate the actuation delay from how the robot answered the plans sent;
3. the task layer decides the action and the modes (fixed, or active inference, Alg. 2);
4. the modes are handed to M3P2I;
5. the plan's start: when the command takes effect, the state predicted for then, the warm
   start moved by the world time since the last plan (:mod:`planner_client.timing`);
6. one M3P2I iteration (sample, roll out, per-mode costs, fuse);
7. the command: the plan, dated, or the robot's safe stop when the task says stop or the
   iteration has no finite cost.

:class:`planner_client.loop.PlannerClient` feeds it states from a world over ZeroMQ;
:mod:`server.inprocess` feeds it a world in the same process.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner_client.attach import Attachments
from planner_client.budget import SampleBudget, budget_config
from planner_client.delay_estimate import ActuationDelayEstimate
from planner_client.guide import Guide
from planner_client.mirror import Mirror, MocapState
from planner_client.model_state import StateSizes, get_full_state
from planner_client.motion import Iteration, MotionPlanner
from planner_client.perception.updater import MapUpdater
from planner_client.task import TaskDecision, TaskLayer
from planner_client.timing import LeadEstimate, predict, steps_between
from planner_client.variants import Identifier
from shared import protocol as P
from shared.scenario import DelayConfig
from shared.scenario.faults import steps_of
from shared.scene import STATE_FIELDS
from shared.timed_plan import TimedPlan, held, mean_hz

log = logging.getLogger("m3p2i.planner")

_NEW_EPISODE = 1.0  # world time going back more than this (s) is a reset, not jitter


class LayoutMismatch(RuntimeError):
    """The world's first state after a handshake has other array sizes than the planner's model
    of the scenario: a bridge of another layout (retrying cannot help). ``mismatches`` names
    each array that differs."""

    def __init__(self, scenario: str, mismatches: list[str]):
        self.scenario, self.mismatches = scenario, mismatches
        super().__init__(self.explain(scenario))

    def explain(self, scenario_ref: str) -> str:
        """The message, with ``m3p2i layout scenario_ref`` as where to find the right layout."""
        return (
            f"the world's state does not fit the planner's model of {self.scenario}: "
            f"{'; '.join(self.mismatches)}. `m3p2i layout {scenario_ref}` prints the "
            f"layout a world must send, index by index"
        )


@dataclass
class LoopStats:
    """What the loop did: iterations, their planning times, the action changes."""

    iterations: int = 0
    plan_times: list[float] = field(default_factory=list)
    map: dict[str, float] | None = None  # the lidar map's MapUpdater.stats(), at its close
    action_changes: list[tuple[float, str, tuple[str, ...]]] = field(default_factory=list)
    final_status: str = ""
    safe_fallbacks: int = 0  # commands that were the safe control because there was no plan
    # the anytime planner's changes: (world s, "samples" or "horizon", before, after, why)
    budget_changes: list[tuple[float, str, int, int, str]] = field(default_factory=list)

    @property
    def hz(self) -> float:
        return mean_hz(self.plan_times)


@dataclass
class Tick:
    """One :meth:`Controller.step`: the state it answered, the task's decision, the M3P2I
    iteration, the plan's date (world s), and world steps since the previous plan's state."""

    state: P.State
    decision: TaskDecision
    iteration: Iteration
    plan_time: float
    start: float
    steps: int


@dataclass
class Parts:
    """One episode's collaborators of a :class:`Controller`, built together from one scenario
    (``planner_client.build.build_parts``): the motion planner, the task layer, the mirror of
    the world in the planner's model, the attachments (welds of held objects), the global
    guide, the maker of the lidars' map (threaded or not: the world's mode is known at
    :meth:`Controller.begin`; None without a lidar), and the maker of the model identifier,
    which needs the world's step (known at :meth:`Controller.begin`) and reweights the
    planner's own variants."""

    motion: MotionPlanner
    task: TaskLayer
    mirror: Mirror
    attachments: Attachments
    guide: Guide | None = None
    identifier: Callable[[float], Identifier | None] = lambda dt: None
    map: Callable[[bool], MapUpdater | None] = lambda threaded: None


Renew = Callable[[int | None], Parts]
"""Builds the parts afresh for a new episode, sampling with the given seed (None: the
planner's own)."""


class Controller:
    """Thesis Alg. 1 without the network: :meth:`begin` an episode, then :meth:`step` on each
    state; the command it returns answers that state (echoes its ``seq``)."""

    def __init__(
        self,
        parts: Parts,
        delays: DelayConfig | None = None,
        renew: Renew | None = None,
    ):
        """``delays``: the robot's unseen delays to compensate (default: the scenario's
        ``planner.delays``). ``renew``: when given, :meth:`begin` with ``new_episode`` gets
        the parts as a fresh process would build them, so no warm start, belief or random
        stream carries over."""
        self.renew = renew
        self._take(parts)
        self.delays = delays or self.motion.problem.scenario.planner.delays
        self.stats = LoopStats()
        self.mode: str | None = None  # the world's: lockstep | realtime (None: lock-step)
        self.dt: float | None = None  # the world's step, s
        self.last: Tick | None = None  # the last step's, for diagnostics
        self._action: tuple[str, tuple[str, ...]] | None = None
        self.robot = self.motion.problem.robot
        self._last_ctrl = self.robot.safe_stop()
        # what the world plays, oldest first: enough plans to cover a lead plus declared delays
        self._sent: deque[TimedPlan] = deque(maxlen=16)
        self._lead: LeadEstimate | None = None
        self._lead_capped = False  # whether the lead was last held at the plan's span
        self._actuation: ActuationDelayEstimate | None = None  # planner.delays.measure
        self.identifier: Identifier | None = None  # planner.model.variants.identify
        self._acting_logged: int | None = None  # the delays last logged, in world steps
        self._ahead_logged = 0
        self._last_start: tuple[float, int] | None = None  # (t_eff, state seq) of the last plan
        self._faults = 0  # consecutive iterations without a plan (Iteration.fault)
        self._over_at: tuple[str, int] | None = None  # (session, seq) of the end last logged
        self.map: MapUpdater | None = None  # the lidars' map, made at begin
        # planner.budget: checked now, the anytime planner made at begin against a real-time world
        budget_config(self.motion.problem.scenario)
        self.budget: SampleBudget | None = None
        self._map_threaded = False

    def begin(
        self, mode: str, dt: float, seed: int | None = None, new_episode: bool = False
    ) -> None:
        """Start (or, after a reconnection, resume) planning against a world that runs in
        ``mode`` (lockstep | realtime) with steps of ``dt`` s: the lead and actuation delay
        estimates start afresh and the plans sent are forgotten. ``new_episode``: the world
        began another episode (``renew``, sampling with the world's ``seed`` when given)."""
        if new_episode:
            self._new_episode(seed)
        self.mode, self.dt = mode, dt
        # a lock-step world reports its state delay in state.lag too (0 without one)
        span = math.ceil(self.motion.dt * self.motion.problem.scenario.planner.horizon / dt)
        measured = mode == "realtime" or self.delays.measure
        self._lead = LeadEstimate(dt, max_steps=span) if measured else None
        self._actuation = None
        self.identifier = self.parts.identifier(dt)
        if self.delays.measure:
            self._actuation = ActuationDelayEstimate(
                self.motion.problem.model, dt, steps_of(self.delays.max_ms, dt)
            )
        # the plans the world played as long ago as the estimates look back must be at hand
        reach = self._actuation.max_steps if self._actuation is not None else 0
        if self.identifier is not None:
            reach = max(reach, self.identifier.reach)
        self._sent = deque(maxlen=max(16, reach + 8))
        self._last_start = None
        self._open_budget(realtime=mode == "realtime")
        self._open_map(threaded=mode == "realtime")

    def _open_map(self, threaded: bool) -> None:
        """Make the lidars' map, or keep the one made for this mode (a reconnection keeps
        what it has seen)."""
        if self.map is not None and self._map_threaded == threaded:
            return
        self._close_map()
        self.map, self._map_threaded = self.parts.map(threaded), threaded

    def _new_episode(self, seed: int | None) -> None:
        """Start over for a new episode of the world (``renew``), sampling with the world's
        episode seed when it sends one."""
        if self.renew is None:
            return
        log.info(
            "new episode%s: planner and task layer rebuilt",
            f" (seed {seed})" if seed is not None else "",
        )
        self.close()
        self._take(self.renew(seed))
        self._action = None
        self._last_ctrl = self.robot.safe_stop()
        self._faults = 0

    def _open_budget(self, realtime: bool) -> None:
        """The anytime planner (``planner.budget``) from the full samples per mode against a
        real-time world; none in lock-step, where the world waits for every plan (so a
        scenario's budget leaves its lock-step episodes as they are)."""
        scenario = self.motion.problem.scenario
        cfg = budget_config(scenario) if realtime else None
        pc = scenario.planner
        self.budget = None if cfg is None else SampleBudget(cfg, pc.samples, pc.horizon)
        self.motion.set_samples(pc.samples)
        self.motion.set_horizon(pc.horizon)
        if cfg is not None:
            self.motion.prepare_horizons(cfg.min_horizon)

    def _spend(self, plan_time: float, now: float) -> None:
        """The anytime planner sees the iteration's time and may change the samples."""
        change = self.budget.observe(plan_time) if self.budget is not None else None
        if change is None:
            return
        if change.what == "samples":
            self.motion.set_samples(change.after)
        else:
            self.motion.set_horizon(change.after)
        self.stats.budget_changes.append(
            (now, change.what, change.before, change.after, change.reason)
        )
        what = "samples per mode" if change.what == "samples" else "horizon steps"
        log.info("t=%.2f s: %s %d -> %d: %s", now, what, change.before, change.after, change.reason)

    def _estimate(self) -> None:
        """The estimators read the transition the mirror just received: the actuation delay,
        and the model variants' weights."""
        if self._actuation is not None:
            self._actuation.observe(
                self.mirror.data, list(self._sent), self.robot.safe_stop(self._last_ctrl)
            )
        if self.identifier is not None:
            self.identifier.observe(
                self.mirror.data,
                self.mirror.received_qpos,
                list(self._sent),
                self.robot.safe_stop(self._last_ctrl),
                self._acting_steps() * self.dt,
            )

    def _take(self, parts: Parts) -> None:
        """Drive ``parts`` from now on."""
        self.parts = parts
        self.motion, self.task = parts.motion, parts.task
        self.mirror, self.attachments, self.guide = parts.mirror, parts.attachments, parts.guide

    def check_layout(self, state: P.State) -> None:
        """Raise :class:`LayoutMismatch` when ``state``'s arrays have other sizes than the
        planner's model (a bridge sending another layout: every state would be dropped)."""
        mismatches = StateSizes.of(self.motion.problem.model).mismatches(
            {name: getattr(state, name) for name in STATE_FIELDS}
        )
        if mismatches:
            raise LayoutMismatch(self.motion.problem.scenario.name, mismatches)

    def over(self, state: P.State) -> bool:
        """Whether ``state`` ends the episode (its status is not ``running``); the status is
        kept in :attr:`stats` and logged."""
        if state.status == "running":
            return False
        self.stats.final_status = state.status
        if (state.session, state.seq) != self._over_at:  # a kept world re-publishes its end
            self._over_at = (state.session, state.seq)
            log.info("episode over: %s at t=%.2f s", state.status, state.time)
        return True

    def step(self, state: P.State) -> P.Command | None:
        """One tick of Alg. 1 (module docstring, steps 1-7): the command answering ``state``,
        with the whole plan dated for when it takes effect; None (logged) when ``state`` does
        not fit the planner's model. :attr:`last` keeps the tick for :meth:`diagnostics`."""
        t0 = time.perf_counter()
        phases = self.motion.phases
        phases.start()
        try:
            x0 = self.mirror.apply(state)  # 1. mirror
        except ValueError as exc:
            log.error("state does not fit the planner's model: %s", exc)
            return None
        if self.attachments.track(self.mirror.data, self.mirror.received_qpos):
            x0 = self.mirror.refresh()
        phases.mark("mirror")
        self._estimate()  # 2. estimate
        phases.mark("estimate")
        if self.map is not None and state.scans:  # the map fused before anything reads it
            self.map.submit(state.scans, self.mirror.data)  # the state's scene: self-filter
            if self.mode != "realtime":  # lock-step: here, so the episode stays its seed's
                self.map.update_now()
        phases.mark("map")
        extras = state.extras
        if self.guide is not None:  # the global path, recomputed beside the planner
            self.guide.update(self.mirror.data, wait=self.mode != "realtime")
            extras = {**extras, **self.guide.extras()}
        phases.mark("guide")
        decision = self.task.decide(self.mirror.data, extras, state.time)  # 3. task
        if self.attachments.welds:
            self.attachments.update(self.mirror.data, self.task.last_observation, state.time)
        self.motion.set_modes(decision.modes)  # 4. modes
        phases.mark("task")
        team = self.motion.team
        if team is not None:  # the others' newest plans: they go so in the rollouts
            team.receive(state.plans)
        start, x0, mocap = self._plan_start(state, x0)  # 5. plan start
        if team is not None:
            team.begin(start, self.motion.horizon)
        phases.mark("start")
        it = self.motion.iterate(x0, mocap)  # 6. M3P2I
        self._note_fault(it, state.time)
        if decision.stop or it.fault is not None:  # 7. command
            # a safe stop keeps the hold_ctrl actuators where they were: a gripper keeps its grip;
            # without a plan (no finite cost) nothing else is safe to send
            ctrl, plan = self.robot.safe_stop(self._last_ctrl), None
            self._sent.append(held(ctrl, start, state.seq))
        else:
            ctrl, plan = it.command, it.plan
            self._sent.append(TimedPlan(start, self.motion.dt, plan, state.seq))
        self._last_ctrl = ctrl
        plan_time = time.perf_counter() - t0
        command = P.Command(
            session=state.session,
            seq=state.seq,
            ctrl=ctrl,
            plan_time=plan_time,
            action=decision.action,
            plan_ctrl=plan,
            plan_t0=None if plan is None else start,
            plan_dt=None if plan is None else self.motion.dt,
            model=self.model_estimate(),
            samples=None if self.budget is None else self.motion.samples,
            robot=team.robot if team is not None else None,
        )
        steps = state.seq - self._last_start[1] if self._last_start else 0
        self._last_start = (start, state.seq)
        self.last = Tick(state, decision, it, plan_time, start, steps)
        self.stats.iterations += 1
        self.stats.plan_times.append(plan_time)
        self._spend(plan_time, state.time)
        key = (decision.action, tuple(decision.modes))
        if key != self._action:
            self._action = key
            self.stats.action_changes.append((state.time, decision.action, tuple(decision.modes)))
            log.info(
                "t=%.2f s: action %s, modes %s", state.time, decision.action, list(decision.modes)
            )
        phases.mark("command")
        return command

    def diagnostics(self) -> P.Diagnostics:
        """What the last :meth:`step` thought, for viewers: the alternatives, the modes'
        weights, each mode's best sampled trajectories (made now, only when asked: a tenth of
        navigation's planning work). Ask before the next step, which reuses the rollouts."""
        tick = self.last
        it = tick.iteration
        return P.Diagnostics(
            seq=tick.state.seq,
            action=tick.decision.action,
            alternatives=list(tick.decision.alternatives),
            mode_names=it.modes,
            mode_weights=it.result.mode_weights.numpy(),
            top=it.top,
            plan_time=tick.plan_time,
            lead=tick.start - tick.state.time,
            steps=tick.steps,
            top_modes=it.top_modes,
            model=self.model_estimate(),
            samples=None if self.budget is None else self.motion.samples,
            guide=self.guide.corners() if self.guide is not None else None,
        )

    def _plan_start(
        self, state: P.State, x0: np.ndarray
    ) -> tuple[float, np.ndarray, MocapState | None]:
        """When the new plan takes effect, the state predicted for then, and the mocap bodies
        there; the warm start is moved by the time since the last plan's start.

        Real time: ``lead`` whole world steps after the state (the largest recent lag), the
        mirror stepped over them under the plans the world is playing. Lock-step: the state's
        own time, as received, plus the declared state delay (``planner.delays``) or, with
        ``estimate``, the one the world reports in ``state.lag``. The actuation delay, declared
        or estimated, is predicted beyond the plan's date (planner_client.timing).
        """
        mocap = self.mirror.mocap()
        ahead = acting = 0  # world steps from the state to the plan's date, and on to when it acts
        lockstep = self.mode != "realtime"
        if self._lead is not None:
            self._lead.observe(state.lag)
            ahead = self._lead.steps()
            if ahead == self._lead.max_steps and not self._lead_capped:
                log.warning(
                    "t=%.2f s: commands arrive %.2f s late, after the plan's whole span: "
                    "planning %d world steps ahead (the span), not more",
                    state.time,
                    state.lag,
                    ahead,
                )
            self._lead_capped = ahead == self._lead.max_steps
        if lockstep and ahead and ahead != self._ahead_logged:
            log.info(
                "t=%.2f s: state delay measured at %d world steps (%.0f ms)",
                state.time,
                ahead,
                ahead * self.dt * 1000,
            )
            self._ahead_logged = ahead
        if lockstep and self.delays.state_ms:
            # in real time the lag runs from the state's measurement time, so the lead already
            # holds the state delay; in lock-step it is the declared one, or the lag measured
            ahead = max(ahead, steps_of(self.delays.state_ms, self.dt))
        acting = self._acting_steps()
        estimated = self._actuation.steps() if self._actuation is not None else None
        if estimated is not None:
            if estimated != self._acting_logged:
                log.info(
                    "t=%.2f s: actuation delay estimated at %d world steps (%.0f ms)",
                    state.time,
                    estimated,
                    estimated * self.dt * 1000,
                )
                self._acting_logged = estimated
        start = state.time
        if ahead + acting:
            dt = self.dt
            model, data = self.mirror.model, self.mirror.data
            predict(
                model,
                data,
                list(self._sent),
                self.robot.safe_stop(self._last_ctrl),
                dt,
                ahead + acting,
                acting * dt,
                self.motion.team,
            )
            x0 = get_full_state(model, data, self.mirror.x0)
            start = float(data.time) - acting * dt  # the same instant, in the mirror's float sums
            if mocap is not None and mocap.moving:
                mocap = MocapState(
                    mocap.pos + mocap.vel * (float(data.time) - state.time), mocap.quat, mocap.vel
                )
        if self._last_start is not None and start >= self._last_start[0] - _NEW_EPISODE:
            self.motion.advance(steps_between(self._last_start[0], start, self.motion.dt))
        return start, x0, mocap

    def _acting_steps(self) -> int:
        """World steps from the world playing a control to the actuators acting on it: the
        estimate once it has one, else the declared delay."""
        estimated = self._actuation.steps() if self._actuation is not None else None
        if estimated is not None:
            return estimated
        return steps_of(self.delays.actuation_ms, self.dt) if self.delays.actuation_ms else 0

    def model_estimate(self) -> dict[str, float] | None:
        """The identified model factors, ``"kind.name" -> factor`` (``mass.box``), or None
        without ``planner.model.variants.identify``."""
        if self.identifier is None:
            return None
        est = self.identifier.estimate()
        return {f"{kind}.{name}": f for kind, values in est.items() for name, f in values.items()}

    def _note_fault(self, it: Iteration, time: float) -> None:
        """Logs a run of iterations without a plan once, when it starts and when it ends."""
        if it.fault is None:
            if self._faults:
                log.info(
                    "t=%.2f s: planning resumed after %d iteration(s) on the safe control",
                    time,
                    self._faults,
                )
            self._faults = 0
            return
        if not self._faults:
            log.warning(
                "t=%.2f s: %s; sending the safe control until a plan is finite again",
                time,
                it.fault,
            )
        self._faults += 1
        self.stats.safe_fallbacks += 1

    def close(self) -> None:
        """Release the motion planner's rollout workers, the guide's thread and the map's."""
        self.motion.close()
        if self.guide is not None:
            self.guide.close()
        self._close_map()

    def _close_map(self) -> None:
        """Stop the map (its figures kept in :attr:`stats`) and empty the field slot."""
        if self.map is None:
            return
        self.map.close()
        self.stats.map = self.map.stats()
        self.motion.problem.field_source.connect(None)
        self.map = None
