"""One episode of the world, without the network: its life from start to summary.

:class:`Episode` owns the world instance (a fresh one per episode, wrapped in
:class:`server.faults.FaultyWorld` when simulated faults are on), its session and state
numbering, the episode log (header, steps, events, summary) and the bookkeeping that turns
commands into logged world steps: when each state was published (for the age of the commands
answering it), the planning time of each command, the task-level action.

:class:`server.app.WorldServer` serves an episode over ZeroMQ (lock-step or real time);
:mod:`server.inprocess` drives one from a planner in the same process. Both call the same
methods in the same order, so a lock-step episode is the same step for step.
"""

from __future__ import annotations

import logging
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from server.episode_log import EpisodeLog, read_log
from server.evaluation.metrics import MetricsEvaluator, describe
from server.evaluation.plan_ages import describe_timing, timing_summary
from server.faults import FaultyWorld
from server.interface import Outcome, World, WorldState, world_name
from server.plan_player import PlanPlayer
from server.team import TeamPlayer
from server.world import SimWorld
from shared import protocol as P
from shared.scenario import Scenario
from shared.scenario.faults import FaultConfig
from shared.timed_plan import TimedPlan, held, mean_hz

log = logging.getLogger("m3p2i.server")

_KEEP_STATE_TIMES = 4096  # states whose times are kept, for the age of the commands answering them


class Episode:
    """A world from ``seed``'s start, logged to ``log_path``: :meth:`publish` its state,
    :meth:`play` (lock-step) or :meth:`apply` (one step) the commands answering it, apply the
    control ops, and :meth:`finish` with the safe stop and the summary."""

    def __init__(
        self,
        scenario: Scenario,
        seed: int,
        log_path: Path,
        world_class: type[World] = SimWorld,
        faults: FaultConfig | None = None,
        mode: str = "lockstep",
        curve: bool = False,
        realtime_factor: float = 1.0,
    ):
        """A fresh world (as a new process would build it), reset, a new session and the
        log's header. ``faults``: the faults the world shows (default: the scenario's);
        ``mode`` and ``curve`` are the server's, for the header (a real-time world's faults run
        on the wall clock, scaled by ``realtime_factor`` into world seconds)."""
        self.scenario = scenario
        self.faults = scenario.faults if faults is None else faults
        self.seed = seed
        self.world: World = world_class(scenario, seed)
        if self.faults.active:
            self.world = FaultyWorld(
                self.world,
                self.faults,
                realtime=mode == "realtime",
                realtime_factor=realtime_factor,
            )
        self.world.reset()
        # the rows a state carries: the perceived objects' are only the sensors' to show
        self._rows = Published.of(scenario, self.world.model)
        self._scans: tuple[int, list] = (-1, [])  # the newest seq published and its readings
        self.metrics = MetricsEvaluator(scenario, self.world.model)  # bad frames fail here
        self.session = secrets.token_hex(4)
        self.seq = 0  # the newest state's number: world steps and ops
        self.steps = 0  # world steps taken (and logged)
        self.resets = 0  # plain resets (control op) within the episode
        self.finished = False  # the summary is written
        self.in_step = False  # a world step is between its physics and its log record
        self.pending: int | None = None  # a signal that landed there, raised once it is logged
        self.lag = 0.0  # of the newest command, world seconds
        self.action = ""
        self.action_changes: list[tuple[float, str]] = []
        self._actions: dict[str, str] = {}  # a team's robots' newest actions (real time)
        self.model: dict[str, float] | None = None  # the planner's identified model (Command)
        self.samples: int | None = None  # its samples per mode, under a planner.budget
        self.horizon: int | None = None  # and its plan's steps (the budget sheds them last)
        self.dropped = 0  # states the simulated link lost
        self._plan_times: list[float] = []
        self._state_times: dict[int, float] = {}  # seq -> world time of recent states
        self._plan_time_of: dict[int, float] = {}  # seq -> planning time, until first applied
        self._published = -1  # the newest seq published (or lost: drop_state)
        # the plans received, each played from its t0 on (a team: each robot's by its own)
        self._player = TeamPlayer(scenario) if scenario.team else PlanPlayer()
        self.log = EpisodeLog(log_path)
        self.log.write(
            "header",
            scenario=scenario.name,
            scenario_hash=scenario.hash,
            source=scenario.source,
            mode=mode,
            dt=self.world.dt,
            session=self.session,
            nq=self.world.model.nq,
            nu=self.world.model.nu,
            seed=seed,
            initial=self.world.initial,
            curve=curve,
            world=world_name(world_class),
            **(self.world.header() if isinstance(self.world, FaultyWorld) else {}),
        )

    @property
    def dt(self) -> float:
        """The world's step, s."""
        return self.world.dt

    @property
    def running(self) -> bool:
        return self.world.status == "running"

    # ------------------------------------------------------------------ states

    def publish(self) -> P.State | None:
        """The world's current state as state ``seq``, its time kept for the age of the
        commands answering it; None when the world's link loses it (:meth:`World.drop_state`,
        asked once per ``seq``: the same state asked for again is delivered). It carries the
        world's sensor readings since the previous ``seq`` (the same again when re-published)."""
        s = self.world.state()
        if self._scans[0] != self.seq:
            self._scans = (self.seq, self.world.scans())
        rows = vars(s) if self._rows is None else self._rows.of_state(s)
        state = P.State(
            session=self.session,
            seq=self.seq,
            time=s.time,
            qpos=rows["qpos"],
            qvel=rows["qvel"],
            act=s.act,
            mocap_pos=rows["mocap_pos"],
            mocap_quat=rows["mocap_quat"],
            status=self.world.status,
            extras=dict(self.world.extras),
            lag=self.lag,
            scans=self._scans[1],
            plans=self._player.forwarded() if self.scenario.team else [],
        )
        self._state_times[self.seq] = state.time
        self._state_times.pop(self.seq - _KEEP_STATE_TIMES, None)
        self._plan_time_of.pop(self.seq - _KEEP_STATE_TIMES, None)
        if self.seq != self._published:
            self._published = self.seq
            if self.world.drop_state():
                self.dropped += 1
                return None
        return state

    # ------------------------------------------------------------------ commands

    def play(
        self,
        cmd: P.Command | list[P.Command],
        steps: int = 1,
        after_step: Callable[[], None] | None = None,
    ) -> None:
        """Lock-step: ``steps`` world steps under ``cmd`` (its plan's knots by time, or its
        ctrl held; the safe control past the plan's end), fewer when the episode ends; then its
        action is noted. One step by default; more emulate, deterministically, a planner that
        slow against a real-time world. ``after_step`` runs after each logged step. A team's
        world plays a list: one command per robot, answering the same state.

        As in real time, a plan applies from its ``plan_t0`` on (:class:`PlanPlayer`): one
        dated ahead of the world (a planner that declares a state delay the world does not
        have) waits, and the plan playing goes on until then. A planner's usual plan is dated
        at the state's time, so it starts at once."""
        cmds = cmd if isinstance(cmd, list) else [cmd]
        cmd = cmds[0]
        self._count_plan(cmd)
        # the lag, as in real time: from the answered state's time (its measurement's) to now;
        # 0 unless the world publishes its states late (a state delay)
        self.lag = max(0.0, self.world.time - self._state_times.get(cmd.seq, self.world.time))
        for c in cmds:
            self._receive_plan(c)
        for _ in range(steps):
            self.apply(*self.playing())
            if after_step is not None:
                after_step()
            if not self.running:
                break
        self.note_action(self._action(cmds))
        self._note_budget(cmd)

    def _action(self, cmds: list[P.Command]) -> str:
        """The action the steps are logged with: a team's as ``a: act, b: act``."""
        if not self.scenario.team:
            return cmds[0].action
        return ", ".join(f"{c.robot}: {c.action}" for c in cmds)

    def _receive_plan(self, cmd: P.Command) -> None:
        if self.scenario.team:
            self._player.receive(self._timed(cmd), cmd.robot)
        else:
            self._player.receive(self._timed(cmd))

    def _note_budget(self, cmd: P.Command) -> None:
        """The planner's identified model, and under a budget its samples and plan steps."""
        self.model, self.samples = cmd.model, cmd.samples
        budgeted = cmd.samples is not None and cmd.plan_ctrl is not None
        self.horizon = len(cmd.plan_ctrl) if budgeted else None

    def state_age(self, seq: int) -> float | None:
        """World seconds since state ``seq`` was measured (None: not a recent state)."""
        sent = self._state_times.get(seq)
        return None if sent is None else self.world.time - sent

    def receive(self, cmd: P.Command) -> None:
        """Real time: a command's lag (published as ``state.lag``), planning time and action;
        its plan goes to the player (:meth:`playing`)."""
        sent = self._state_times.get(cmd.seq)
        if sent is not None:
            self.lag = max(0.0, self.world.time - sent)
        self._count_plan(cmd)
        if self.scenario.team:  # each robot's newest action
            self._actions[cmd.robot] = cmd.action
            self.note_action(", ".join(f"{r}: {a}" for r, a in sorted(self._actions.items())))
        else:
            self.note_action(cmd.action)
        self._note_budget(cmd)
        self._receive_plan(cmd)

    def playing(self) -> tuple[np.ndarray | None, int]:
        """The control the plans received give for the world's time, and the state ``seq`` its
        plan answered: ``(None, seq)`` when that plan ran out, ``(None, -1)`` before any."""
        if self.scenario.team:
            ctrl, plan = self._player.control(self.world.time, self.world.ctrl)
        else:
            ctrl, plan = self._player.control(self.world.time)
        return ctrl, (plan.seq if plan is not None else -1)

    def drop_plans(self, robot: str | None = None) -> None:
        """Forget the plans received (commands gone stale: the safe control until the next);
        in a team, ``robot``'s only (None: every robot's)."""
        if robot is not None:
            self._player.clear(robot)
        else:
            self._player.clear()

    def _timed(self, cmd: P.Command) -> TimedPlan:
        """The plan ``cmd`` carries, as the world plays it; a command without a plan holds its
        ``ctrl`` until the next one (protocol 1's meaning)."""
        if cmd.has_plan:
            return TimedPlan(cmd.plan_t0, cmd.plan_dt, cmd.plan_ctrl, cmd.seq)
        return held(cmd.ctrl, self.world.time, cmd.seq)

    def _count_plan(self, cmd: P.Command) -> None:
        """Its planning time counts (Hz statistics) once, on the first step it drives."""
        if cmd.plan_time > 0:
            self._plan_time_of[cmd.seq] = cmd.plan_time

    def note_action(self, action: str) -> None:
        """The task-level action the steps from now on are logged with; a change is an event."""
        if action != self.action:
            self.action = action
            self.action_changes.append((self.world.time, action))
            self.log.event("action", time=self.world.time, action=action)

    def apply(
        self, ctrl: np.ndarray | None, source: int = -1, cmd_age: float | None = None
    ) -> None:
        """One world step under ``ctrl`` (None: the safe control), planned from state
        ``source`` (-1: none); the step's log record has the control's age (world seconds since
        that state) and source, from which server.evaluation.plan_ages tells whether the planner
        kept up. Real time also records ``cmd_age``: wall seconds from the newest command's
        arrival to the moment this step's control was chosen (what the stale-command watchdog
        compares with ``command_timeout``; None before the first command and in lock-step), so
        a soak test can prove from the log that no stale command drove the robot.

        A signal that lands between the physics and the log record (:attr:`pending`) is
        raised as KeyboardInterrupt once the step is logged: the log holds every step taken."""
        now = self.world.time
        source = source if ctrl is not None else -1
        age = now - self._state_times.get(source, now) if source >= 0 else 0.0
        plan_time = self._plan_time_of.pop(source, 0.0)
        if plan_time:
            self._plan_times.append(plan_time)
        self.in_step = True  # from the physics to its log record: no signal between
        try:
            self.world.step(self.world.safe_command() if ctrl is None else ctrl)
            for event in self.world.events:
                log.info("disturbance: %s moved at t=%.2f s", event["object"], event["time"])
                self.log.event("disturbance", **event)
            self.world.events.clear()
            self.seq += 1
            self.steps += 1
            s = self.world.true_state()
            # the planner's identified model, when it identifies one (planner.model.variants)
            identified = {} if self.model is None else {"model": self.model}
            if self.samples is not None:  # the anytime planner's samples per mode
                identified["samples"] = self.samples
            if self.horizon is not None:  # and its horizon
                identified["horizon"] = self.horizon
            self.log.write(
                "step",
                seq=self.seq,
                time=s.time,
                qpos=s.qpos,
                qvel=s.qvel,
                act=s.act,
                mocap_pos=s.mocap_pos,
                mocap_quat=s.mocap_quat,
                ctrl=self.world.ctrl,
                action=self.action,
                safe=ctrl is None,
                plan_seq=source,
                age=age,
                plan_time=plan_time,
                cmd_age=cmd_age,
                extras=self.world.extras,
                **identified,
            )
        finally:
            self.in_step = False
        if self.pending is not None:
            signum, self.pending = self.pending, None
            raise KeyboardInterrupt(f"signal {signum}")

    # ------------------------------------------------------------------ control ops

    def move(self, name: str, pos: np.ndarray, quat: np.ndarray | None = None) -> None:
        """Control op ``move``: the object put at ``pos`` (``quat``), logged as a disturbance;
        a new state (a lock-step world waits for the command answering the moved one). A robot
        body or an unknown name raises ValueError, logged as refused."""
        try:
            event = self.world.move_object(name, pos, quat)
        except ValueError as exc:
            log.warning("control move refused: %s", exc)
            self.log.event("control_refused", op="move", object=name, reason=str(exc))
            raise
        log.info("disturbance: %s moved by a control op at t=%.2f s", name, event["time"])
        self.log.event("control", op="move", object=name)
        self.log.event("disturbance", **event)
        self.seq += 1

    def reset(self) -> None:
        """Control op ``reset`` within the episode: the world back to its start, a new state of
        a new session, so that the planner handshakes again and starts over as for a new
        episode (task layer, beliefs, welds of held objects and warm start as a fresh planner
        has them: the old ones belong to a world that is gone). Logged as a ``reset`` event
        with the world time it cut short; the log and its summary go on (docs/protocol.md)."""
        cut = self.world.time
        self.world.reset()
        self.session = secrets.token_hex(4)
        self.seq += 1
        self.resets += 1
        self.lag = 0.0
        self.action = ""  # the restarted planner's first action is a change
        self._player.clear()  # plans dated before the reset are void
        self.log.event("reset", time=cut, session=self.session, seq=self.seq)

    def abort(self) -> None:
        """End the episode as ``stopped`` (a shutdown, Ctrl-C, a step limit)."""
        self.world.status = "stopped"

    def stop_world(self) -> None:
        """The world's safe stop; its failure is logged loudly, and the summary still written."""
        try:
            self.world.stop()
        except Exception as exc:
            log.exception("the world's safe stop failed: the robot may still be moving")
            self.log.event("stop_failed", reason=f"{type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ the end

    def finish(self, rejected: int = 0) -> Outcome:
        """The episode's end, whatever ended it: the robot's safe stop, the outcome (a world
        still running is ``stopped``), the metrics and the summary record (``rejected``: the
        bad messages the server refused); the log is closed. The outcome's measures gain
        ``planner_hz``."""
        self.stop_world()  # a robot holds still whatever ended the episode
        if self.running:  # ended by a seeded reset, a shutdown, a limit
            self.abort()
        outcome = self.world.outcome()
        hz = mean_hz(self._plan_times)
        metrics, timing = self.evaluate(outcome.status)
        self.log.write(
            "summary",
            status=outcome.status,
            time=outcome.time,
            measures=outcome.measures,
            planner_hz=hz,
            steps=self.steps,
            rejected=rejected,
            actions=self.action_changes,
            **({"resets": self.resets} if self.resets else {}),
            **({"dropped": self.dropped} if self.faults.active else {}),
            metrics=metrics,
            timing=timing,
        )
        self.log.close()
        self.finished = True
        outcome.measures["planner_hz"] = hz
        return outcome

    def evaluate(self, status: str) -> tuple[dict | None, dict | None]:
        """server.evaluation's metrics and timing of the logged steps (the log is line-buffered,
        so complete on disk). A failure here is logged, never allowed to cost the summary."""
        try:
            records = read_log(self.log.path)
            metrics = self.metrics.evaluate(records, status=status)
            timing = timing_summary(records)
        except Exception:
            log.exception("could not compute the episode metrics")
            return None, None
        log.info("metrics: %s", describe(metrics))
        log.info("timing: %s", describe_timing(timing))
        return metrics.as_dict(), timing

    def close(self) -> None:
        """Release the world (and the log, when the episode did not finish)."""
        self.log.close()
        self.world.close()


@dataclass(frozen=True)
class Published:
    """The rows of the world model's state arrays that a state carries, in order: all but the
    perceived objects' (nothing of theirs reaches the planner but scans, and its model has no
    such rows). A free perceived object's joint leaves its 7 ``qpos`` and 6 ``qvel`` rows out,
    a fixed one its ``mocap`` row; what is left is the planner's model's layout, as its joints
    and mocap bodies keep their order without them. ``qpos [nq']``, ``qvel [nv']``, ``mocap
    [nmocap']``: indices into the world's arrays."""

    qpos: np.ndarray
    qvel: np.ndarray
    mocap: np.ndarray

    @classmethod
    def of(cls, scenario: Scenario, model: mujoco.MjModel) -> Published | None:
        """The rows of ``scenario``'s world ``model`` that a state carries; None when that is
        every row (no perceived object)."""
        perceived = {o.name for o in scenario.world.objects if o.perceived}
        if not perceived:
            return None
        hidden = [model.body(name).id for name in perceived]
        qpos, qvel = np.ones(model.nq, bool), np.ones(model.nv, bool)
        for j in np.flatnonzero(np.isin(model.jnt_bodyid, hidden)):  # free joints, 7 + 6 rows
            qpos[model.jnt_qposadr[j] : model.jnt_qposadr[j] + 7] = False
            qvel[model.jnt_dofadr[j] : model.jnt_dofadr[j] + 6] = False
        mocap = np.ones(model.nmocap, bool)
        mocap[[int(model.body_mocapid[b]) for b in hidden if model.body_mocapid[b] >= 0]] = False
        return cls(np.flatnonzero(qpos), np.flatnonzero(qvel), np.flatnonzero(mocap))

    def of_state(self, s: WorldState) -> dict[str, np.ndarray]:
        """``s``'s carried rows: ``qpos``, ``qvel``, ``mocap_pos``, ``mocap_quat``."""
        return {
            "qpos": s.qpos[self.qpos],
            "qvel": s.qvel[self.qvel],
            "mocap_pos": s.mocap_pos[self.mocap],
            "mocap_quat": s.mocap_quat[self.mocap],
        }

    def into(self, data: mujoco.MjData, state: P.State) -> dict[str, np.ndarray]:
        """The world's arrays of a received ``state``: its rows where they belong, the others
        (the perceived objects') as ``data`` has them (where the file puts them)."""
        out = {}
        for name, rows in (
            ("qpos", self.qpos),
            ("qvel", self.qvel),
            ("mocap_pos", self.mocap),
            ("mocap_quat", self.mocap),
        ):
            full = getattr(data, name).copy()
            full[rows] = getattr(state, name)
            out[name] = full
        return out
