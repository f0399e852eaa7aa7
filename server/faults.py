"""A world with simulated faults: :class:`FaultyWorld` wraps any :class:`World` and makes it
behave like a robot in a lab (the scenario's ``faults:`` section or ``--faults``;
docs/faults.md).

- actuation delay: the commands pass a delay line before they reach the inner world;
- state delay and noise: each state is measured (noise added, free objects' velocities
  withheld) when it happens and published ``state_delay_ms`` later;
- control period: the actuators take a new command every ``k`` world steps only, and hold it
  between;
- binary gripper: the gripper's command snapped to open or closed;
- model mismatch: the inner simulation's masses, frictions and actuator gains scaled by
  factors drawn from the seed (the planner builds its model from the YAML: the nominal one);
- drops: :meth:`FaultyWorld.drop_state` tells the server to lose a state message;
- scans: the sensors' ranges with Gaussian noise and rays without a return, each reading
  delivered ``scan_latency_ms`` after its measurement, stamped with its measurement's time.

Lock-step: delays count world steps (``ms / dt`` rounded up) and every draw comes from generators
seeded by the episode seed, so a faulty episode repeats exactly. Real-time: delays are world
seconds on the wall clock, scaled by the world's ``realtime_factor`` (a world at half speed
delays twice as long in wall time), so they are the world steps a planner declares
(``--compensate``) at any factor. Nothing here reads the wall clock in lock-step.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from server.interface import Outcome, World, WorldError, WorldState
from server.sensors import no_return
from server.world import SimWorld
from shared.scans import Scan
from shared.scenario.faults import FaultConfig, steps_of
from shared.scene import contact_friction

# independent generator streams per fault, so that turning one fault on leaves the others' draws
_NOISE, _DROPS, _MISMATCH, _SCANS = 1, 2, 3, 4


class DelayLine:
    """Values pushed with a stamp come out ``delay`` later: :meth:`out` is the newest value
    pushed at or before ``now - delay`` (``before`` until one is: None, or the oldest value)."""

    def __init__(self, delay: float, oldest_first: bool = False):
        self.delay = delay
        self.oldest_first = oldest_first
        self._queue: deque[tuple[float, Any]] = deque()
        self._current: Any = None

    def clear(self) -> None:
        self._queue.clear()
        self._current = None

    def push(self, stamp: float, value: Any) -> None:
        self._queue.append((stamp, value))

    def out(self, now: float) -> Any:
        while self._queue and self._queue[0][0] <= now - self.delay:
            self._current = self._queue.popleft()[1]
        if self._current is None and self.oldest_first and self._queue:
            return self._queue[0][1]
        return self._current


def draw_mismatch(
    model: mujoco.MjModel, world: World, config: FaultConfig, seed: int
) -> dict[str, dict[str, float]]:
    """Scale ``model`` in place by factors drawn from ``seed``, uniform in ``[1 - f, 1 + f]``:
    each scenario object's bodies' masses and inertias (``mass``), its geoms' frictions
    (``friction``), each actuator's gain and bias (``gain``: kp and kv of a servo). Returns the
    factors (object or actuator name -> factor) for the episode log."""
    m = config.mismatch
    rng = np.random.default_rng([seed, _MISMATCH])
    factors: dict[str, dict[str, float]] = {"mass": {}, "friction": {}, "gain": {}}
    given = {kind: m.factors.get(kind, {}) for kind in factors}
    # the frictions of the objects' contacts, before any object's is scaled
    touching = [o.name for o in world.scenario.world.objects if not o.visual]
    priority, frictions = contact_friction(model, [model.body(n).id for n in touching])
    contacts = {n: frictions[model.body(n).id] for n in touching if m.friction_of == "contacts"}
    for obj in world.scenario.world.objects:
        body = model.body(obj.name).id
        # drawn whether used or not: each object's draws stay the same as other faults change
        f_mass = given["mass"].get(obj.name, 1.0 + m.mass * rng.uniform(-1.0, 1.0))
        f_friction = given["friction"].get(obj.name, 1.0 + m.friction * rng.uniform(-1.0, 1.0))
        if (m.mass or obj.name in given["mass"]) and not obj.fixed:  # a fixed one moves nothing
            model.body_mass[body] *= f_mass
            model.body_inertia[body] *= f_mass
            factors["mass"][obj.name] = float(f_mass)
        if (m.friction or obj.name in given["friction"]) and not obj.visual:  # visual: no contact
            if obj.name in contacts:
                geoms, friction = contacts[obj.name]
                model.geom_friction[geoms] = friction * f_friction
                model.geom_priority[:] = priority
            else:
                model.geom_friction[model.geom_bodyid == body] *= f_friction
            factors["friction"][obj.name] = float(f_friction)
    for a in range(model.nu):
        name = model.actuator(a).name or str(a)
        f_gain = given["gain"].get(name, 1.0 + m.gain * rng.uniform(-1.0, 1.0))
        if m.gain or name in given["gain"]:
            # force = gain * ctrl + bias0 + bias1 * length + bias2 * velocity: scaling the gain
            # and the bias together scales a servo's kp and kv, a motor's gear
            model.actuator_gainprm[a, 0] *= f_gain
            model.actuator_biasprm[a, :3] *= f_gain
            factors["gain"][name] = float(f_gain)
    known = {
        "mass": [o.name for o in world.scenario.world.objects if not o.fixed],
        "friction": [o.name for o in world.scenario.world.objects if not o.visual],
        "gain": [model.actuator(a).name or str(a) for a in range(model.nu)],
    }
    for kind, named in given.items():
        for name in set(named) - set(known[kind]):
            raise WorldError(
                f"faults.mismatch.factors.{kind}.{name}: no such "
                f"{'actuator' if kind == 'gain' else 'object'} to scale; one of: "
                + (", ".join(known[kind]) or "(none)")
            )
    return factors


class FaultyWorld(World):
    """``inner`` with the faults of ``config``; the server uses it as any world. ``realtime``:
    delays in world seconds, read as ``clock()`` (wall seconds) times ``realtime_factor`` (the
    world seconds a wall second holds); else in world steps."""

    def __init__(
        self,
        inner: World,
        config: FaultConfig,
        realtime: bool = False,
        clock: Callable[[], float] = time.monotonic,
        realtime_factor: float = 1.0,
    ):
        # World.__init__ is not called: the inner world owns the model and the episode's state
        self.inner = inner
        self.config = config
        self.realtime = realtime
        self._clock = clock
        self.realtime_factor = realtime_factor
        dt = inner.dt
        if realtime:
            self._actuation = DelayLine(config.actuation_delay_ms / 1000.0)
            self._states = DelayLine(config.state_delay_ms / 1000.0, oldest_first=True)
        else:
            self._actuation = DelayLine(steps_of(config.actuation_delay_ms, dt))
            self._states = DelayLine(steps_of(config.state_delay_ms, dt), oldest_first=True)
        self.period_steps = max(1, steps_of(config.control_period_ms, dt))
        # world seconds from a reading's measurement to its delivery (lock-step: whole steps)
        self.scan_latency = config.scan_latency_ms / 1000.0
        if not realtime:
            self.scan_latency = steps_of(config.scan_latency_ms, dt) * dt
        self.mismatch: dict[str, dict[str, float]] = {}
        if config.mismatch.active:
            if not isinstance(inner, SimWorld):
                raise WorldError(
                    f"faults.mismatch scales a simulated model; the world "
                    f"{type(inner).__name__} simulates none (set the mismatch "
                    f"fractions to 0)"
                )
            self.mismatch = draw_mismatch(inner.model, inner, config, inner.seed)
            mujoco.mj_setConst(inner.model, inner.data)
        self._gripper = (
            [inner.robot.ctrl_names.index(n) for n in inner.robot.hold_ctrl]
            if config.gripper == "binary"
            else []
        )
        self._index_joints(inner.model)
        self.reset()

    # the inner world's attributes, read and written through
    scenario = property(lambda self: self.inner.scenario)
    seed = property(lambda self: self.inner.seed)
    model = property(lambda self: self.inner.model)
    robot = property(lambda self: self.inner.robot)
    extras = property(lambda self: self.inner.extras)
    events = property(lambda self: self.inner.events)
    initial = property(lambda self: self.inner.initial)
    data = property(lambda self: self.inner.data)

    @property
    def status(self) -> str:
        return self.inner.status

    @status.setter
    def status(self, value: str) -> None:
        self.inner.status = value

    @property
    def time(self) -> float:
        return self.inner.time

    @property
    def ctrl(self) -> np.ndarray:
        return self.inner.ctrl

    def _index_joints(self, model: mujoco.MjModel) -> None:
        """Where the noise goes: qpos addresses by joint type, free joints' velocities."""
        types = model.jnt_type
        adr = model.jnt_qposadr
        # a slide of a body on the world is a mobile base's localisation (a tracker's noise);
        # one deeper in the tree, a finger's, is an encoder's and left exact
        on_world = model.body_parentid[model.jnt_bodyid] == 0
        self._slide = adr[(types == mujoco.mjtJoint.mjJNT_SLIDE) & on_world]
        self._hinge = adr[types == mujoco.mjtJoint.mjJNT_HINGE]
        free = types == mujoco.mjtJoint.mjJNT_FREE
        self._free_pos = adr[free]
        self._quats = np.concatenate([adr[free] + 3, adr[types == mujoco.mjtJoint.mjJNT_BALL]])
        self._free_dof = model.jnt_dofadr[free]

    def _now(self) -> float:
        return self._clock() * self.realtime_factor if self.realtime else float(self._steps)

    # ------------------------------------------------------------------ the episode

    def reset(self) -> None:
        self.inner.reset()
        self._steps = 0
        self._noise = np.random.default_rng([self.seed, _NOISE])
        self._drops = np.random.default_rng([self.seed, _DROPS])
        self._scan_noise = np.random.default_rng([self.seed, _SCANS])
        self._scan_line: list[Scan] = []  # readings measured, not yet delivered
        self._actuation.clear()
        self._states.clear()
        self._held: np.ndarray | None = None
        self._record()

    def step(self, ctrl: np.ndarray) -> None:
        """``ctrl`` enters the actuation delay line; the inner world steps under what comes out
        of it (the safe control before anything has), sampled every ``period_steps``."""
        ctrl = self.clip(ctrl)
        for i in self._gripper:
            lo, hi = self.model.actuator_ctrlrange[i]
            ctrl[i] = hi if ctrl[i] >= (lo + hi) / 2 else lo
        now = self._now()
        self._actuation.push(now, ctrl)
        arrived = self._actuation.out(now)
        if self._held is None or self._steps % self.period_steps == 0:
            self._held = self.inner.safe_command() if arrived is None else arrived
        self.inner.step(self._held)
        self._steps += 1
        self._record()

    def _record(self) -> None:
        """Measure the state now (noise drawn once, so re-publishing it draws nothing) into
        the state delay line."""
        self._states.push(self._now(), self.measure(self.inner.state()))

    def measure(self, s: WorldState) -> WorldState:
        """``s`` as a sensor reports it: Gaussian noise on positions, hinge joints and
        orientations (quaternions turned by a random rotation and kept unit), free objects'
        velocities withheld."""
        c = self.config
        qpos, qvel = s.qpos.copy(), s.qvel.copy()
        mocap_pos, mocap_quat = s.mocap_pos.copy(), s.mocap_quat.copy()
        if c.position_noise_m:
            for a in self._free_pos:
                qpos[a : a + 3] += self._noise.normal(0.0, c.position_noise_m, 3)
            qpos[self._slide] += self._noise.normal(0.0, c.position_noise_m, len(self._slide))
            mocap_pos += self._noise.normal(0.0, c.position_noise_m, mocap_pos.shape)
        if c.joint_noise_rad:
            qpos[self._hinge] += self._noise.normal(0.0, c.joint_noise_rad, len(self._hinge))
        if c.angle_noise_rad:
            for a in self._quats:
                qpos[a : a + 4] = self._turn(qpos[a : a + 4])
            for i in range(len(mocap_quat)):
                mocap_quat[i] = self._turn(mocap_quat[i])
        if c.hide_velocities:
            for d in self._free_dof:
                qvel[d : d + 6] = 0.0
        return WorldState(
            time=s.time,
            qpos=qpos,
            qvel=qvel,
            act=s.act.copy(),
            mocap_pos=mocap_pos,
            mocap_quat=mocap_quat,
        )

    def _turn(self, quat: np.ndarray) -> np.ndarray:
        """``quat`` (w x y z) turned by a rotation vector with σ ``angle_noise_rad`` per axis."""
        rotvec = self._noise.normal(0.0, self.config.angle_noise_rad, 3)
        turn = np.zeros(4)
        mujoco.mju_axisAngle2Quat(
            turn, rotvec / max(np.linalg.norm(rotvec), 1e-300), float(np.linalg.norm(rotvec))
        )
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, np.asarray(quat, float), turn)
        return out / np.linalg.norm(out)

    def state(self) -> WorldState:
        """The measured state ``state_delay_ms`` ago (the start state until one is that old)."""
        return self._states.out(self._now())

    def true_state(self) -> WorldState:
        return self.inner.state()

    def drop_state(self) -> bool:
        return bool(self.config.drop_rate) and self._drops.random() < self.config.drop_rate

    def scans(self) -> list[Scan]:
        """The inner world's readings with the scan faults, drawn once each as they are taken
        from it (in lock-step, at each published state: repeatable), delivered once
        ``scan_latency`` world seconds have passed since their measurement."""
        self._scan_line += [self._degrade(scan) for scan in self.inner.scans()]
        due = self.time - self.scan_latency + 1e-9
        out = [scan for scan in self._scan_line if scan.time <= due]
        self._scan_line = [scan for scan in self._scan_line if scan.time > due]
        return out

    def _degrade(self, scan: Scan) -> Scan:
        """``scan`` with Gaussian noise (σ ``scan_noise_m``) on its returns, kept within its
        band, and a share ``scan_dropout`` of its rays without a return; every ray draws, so a
        reading's draws do not depend on what it saw."""
        c = self.config
        if not (c.scan_noise_m or c.scan_dropout):
            return scan
        ranges = np.array(scan.ranges, dtype=float)
        if c.scan_noise_m:
            noisy = ranges + self._scan_noise.normal(0.0, c.scan_noise_m, ranges.shape)
            hits = scan.hits()
            ranges[hits] = np.clip(noisy[hits], scan.range_min, scan.range_max)
        if c.scan_dropout:
            ranges[self._scan_noise.random(ranges.shape) < c.scan_dropout] = no_return(
                scan.range_max
            )
        return dataclasses.replace(scan, ranges=ranges)

    def outcome(self) -> Outcome:
        return self.inner.outcome()

    def safe_command(self) -> np.ndarray:
        return self.inner.safe_command()

    def stop(self) -> None:
        self.inner.stop()

    def move_object(self, name: str, pos, quat=None) -> dict:
        event = self.inner.move_object(name, pos, quat)
        self._record()  # measured now, published once the state delay has passed
        return event

    def close(self) -> None:
        self.inner.close()

    def header(self) -> dict:
        """What the episode log's header records of the faults: the config, the mismatch
        factors drawn, the delays and control period in the units this mode counts (a log
        written before the rename names them ``hardware*``:
        :func:`server.evaluation.log_reader.faults` reads both)."""
        unit = "s" if self.realtime else "steps"
        return {
            "faults": self.config.to_dict(),
            "faults_mismatch": self.mismatch,
            "faults_delays": {
                "actuation": self._actuation.delay,
                "state": self._states.delay,
                "unit": unit,
                "control_period_steps": self.period_steps,
            },
        }
