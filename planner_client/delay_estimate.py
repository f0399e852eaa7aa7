"""The robot's actuation delay, estimated online from how it answers the controls it was sent.

No message shows an actuation delay (a command reaches the world, the drives act on it later;
docs/faults.md), but the robot's motion does: between two received states, the planner's
own model stepped under the controls the world played ``d`` world steps earlier predicts the
robot's new velocities best for the true ``d``. :class:`ActuationDelayEstimate` keeps, for each
candidate ``d`` in ``0..max_steps``, an exponentially weighted mean of that one-state prediction
error over the robot's own degrees of freedom (objects excluded: their motion is the world's),
and answers the candidate with the smallest. It needs the robot to move: until the errors
differ by a margin, it answers None (the declared delay, if any, stands).

The state delay needs no estimate: a world stamps each state with its measurement time and
reports, in ``state.lag``, how long after it the command that answered it arrived
(planner_client.timing.LeadEstimate), in real time and lock-step alike.
"""

from __future__ import annotations

import logging

import mujoco
import numpy as np

from planner_client.timing import predict
from shared.timed_plan import TimedPlan

log = logging.getLogger("m3p2i.planner")


class ActuationDelayEstimate:
    """Candidates ``0..max_steps`` world steps; ``forget``: weight of a new error in each
    candidate's running mean; ``min_states``: observations before an answer."""

    def __init__(
        self,
        model: mujoco.MjModel,
        world_dt: float,
        max_steps: int,
        forget: float = 0.05,
        min_states: int = 20,
        margin: float = 0.8,
    ):
        self.model = model
        self.world_dt = world_dt
        self.max_steps = max_steps
        self.forget = forget
        self.min_states = min_states
        self.margin = margin
        self.errors = np.zeros(max_steps + 1)  # [D + 1] running mean squared error
        self.observed = 0
        free = model.jnt_type == mujoco.mjtJoint.mjJNT_FREE
        robot = [j for j in range(model.njnt) if not free[j]]
        self._dofs = np.array([model.jnt_dofadr[j] for j in robot], dtype=int)  # [R]
        self._scratch = mujoco.MjData(model)
        # the whole state the prediction starts from: the physics, and what decides the model's
        # constraints and fixed bodies (a carried cube's weld, the mocap poses; MuJoCo 4's
        # FULLPHYSICS has neither)
        S = mujoco.mjtState
        self._state_kind = (
            S.mjSTATE_FULLPHYSICS
            | S.mjSTATE_EQ_ACTIVE
            | S.mjSTATE_MOCAP_POS
            | S.mjSTATE_MOCAP_QUAT
            | S.mjSTATE_USERDATA
        )
        # the longest gap between two states that is scored: as long as the longest delay
        # candidate (a planner that slow sees no state in between), 3 steps at least
        self.max_gap = max(3, max_steps)
        self.too_long = 0  # gaps not scored for their length
        self._prev: tuple[float, np.ndarray] | None = None

    def observe(self, data: mujoco.MjData, plans: list[TimedPlan], safe: np.ndarray) -> None:
        """``data``: the mirror of the newest received state (its ``time`` the measurement's).
        Scores every candidate on the step(s) from the previous state to this one, played
        under ``plans`` (the plans sent, oldest first; ``safe`` before any)."""
        time = float(data.time)
        state = np.zeros(mujoco.mj_stateSize(self.model, self._state_kind))
        mujoco.mj_getState(self.model, data, state, self._state_kind)
        prev, self._prev = self._prev, (time, state)
        if prev is None or not len(self._dofs):
            return
        steps = round((time - prev[0]) / self.world_dt)
        if steps > self.max_gap:
            self.too_long += 1
            if self.too_long in (1, 10, 100) or self.too_long % 1000 == 0:
                log.warning(
                    "actuation delay estimate: states %d world steps apart, over the "
                    "%d it scores: not scored (%d such gaps so far); a planner this "
                    "slow gets no estimate: raise planner.delays.max_ms",
                    steps,
                    self.max_gap,
                    self.too_long,
                )
            return
        if steps < 1:  # a new episode (time went back), or the same state
            return
        target = data.qvel[self._dofs]
        m, d = self.model, self._scratch
        errors = np.empty_like(self.errors)
        for k in range(self.max_steps + 1):
            mujoco.mj_setState(m, d, prev[1], self._state_kind)
            predict(m, d, plans, safe, self.world_dt, steps, actuation_delay=k * self.world_dt)
            errors[k] = float(np.sum((d.qvel[self._dofs] - target) ** 2))
        w = self.forget if self.observed else 1.0
        self.errors[:] = w * errors + (1 - w) * self.errors
        self.observed += 1

    def steps(self) -> int | None:
        """The candidate with the smallest mean error, once ``min_states`` were scored and it
        beats the others' median by ``margin`` (its error at most that fraction of it); else
        None: the robot has not moved enough to tell."""
        if self.observed < self.min_states:
            return None
        best = int(np.argmin(self.errors))
        if not self.errors[best] < self.margin * float(np.median(self.errors)):
            return None  # (all equal, zero included: the controls told nothing apart)
        return best
