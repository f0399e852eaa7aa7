"""The other robots of a team inside this planner's rollouts: each goes as its planner said.

A team's planner (``m3p2i-planner --robot NAME``) plans its own robot's controls only; its model
is the whole world, every robot in it. The world forwards each robot's newest dated plan with
every state (``state.plans``); here those plans fill the other robots' controls at each rollout
step's time, the same for all samples, so that every sample meets the others where they will be
and pushes, passes or waits with them in the physics itself. Past a plan's last knot its last
control is held (a velocity-driven robot goes on at that velocity); a robot without a plan, or
whose plan ended before the horizon starts, holds its safe control (stands still). With
``planner.shared_plans: false`` the plans are ignored: the others stand still in every rollout,
obstacles seen only in the state.

Right of way (prioritized planning): ``planner.passes_through: [b]`` lets this robot plan as if
``b`` were not there while ``b``'s plan arrives (``b`` sees this robot's plan and gives way);
once ``b``'s planner goes quiet, ``b`` is an obstacle in the rollouts again.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from shared import protocol as P
from shared.scenario import Scenario
from shared.timed_plan import TimedPlan


class TeamRollouts:
    """Widens this robot's controls ``[S, T, nu_own]`` to the world's ``[S, T, nu]``."""

    def __init__(self, scenario: Scenario, model: mujoco.MjModel, dt: float, horizon: int):
        names = [model.actuator(i).name for i in range(model.nu)]
        self.robot = scenario.member
        self.own = np.array([names.index(n) for n in scenario.robot.spec.ctrl_names])
        self.use_plans = scenario.planner.shared_plans
        self.safe = np.zeros(model.nu)
        self.columns: dict[str, np.ndarray] = {}
        for m in scenario.team:
            cols = np.array([names.index(n) for n in m.robot.spec.ctrl_names])
            self.safe[cols] = m.robot.spec.safe_ctrl
            if m.name != self.robot:
                self.columns[m.name] = cols
        self.dt, self.horizon = dt, horizon
        # planner.passes_through: those robots' geoms, and their contact bits to restore
        self.model = model
        self.through = {
            name: np.flatnonzero(
                [model.body(int(b)).name.startswith(f"{name}/") for b in model.geom_bodyid]
            )
            for name in scenario.planner.passes_through
        }
        self._bits = {
            name: (model.geom_contype[g].copy(), model.geom_conaffinity[g].copy())
            for name, g in self.through.items()
        }
        self.plans: dict[str, TimedPlan] = {}
        self._own = torch.from_numpy(self.own)
        self._others = torch.zeros(horizon, model.nu, dtype=torch.float64)  # [T, nu]

    def receive(self, plans: list[P.RobotPlan]) -> None:
        """The others' newest plans from a state (this robot's own is left out). A robot whose
        plan the state does not carry (its planner went quiet, a new episode) stands still."""
        if self.use_plans:
            self.plans = {
                p.robot: TimedPlan(p.t0, p.dt, p.ctrl) for p in plans if p.robot in self.columns
            }

    def at(self, t: float) -> np.ndarray:
        """The world's control ``[nu]`` at world time ``t`` as the others' plans give it (this
        robot's columns: its safe control)."""
        u = self.safe.copy()
        for name, plan in self.plans.items():
            if t + 1e-9 < plan.t0:
                continue  # not started: the robot goes on as before, unknown here: held
            knot = plan.index(t)
            u[self.columns[name]] = plan.ctrl[-1 if knot is None else knot]
        return u

    def begin(self, t0: float, horizon: int) -> None:
        """The others' controls over the rollouts starting at world time ``t0``: ``[T, nu]``;
        a robot this one passes through has no contacts in them while its plan arrives."""
        self.horizon = horizon
        for name, geoms in self.through.items():
            contype, conaffinity = self._bits[name]
            giving_way = name in self.plans
            self.model.geom_contype[geoms] = 0 if giving_way else contype
            self.model.geom_conaffinity[geoms] = 0 if giving_way else conaffinity
        self._others = torch.from_numpy(
            np.stack([self.at(t0 + k * self.dt) for k in range(horizon)])
        )

    def widen(self, V: torch.Tensor) -> torch.Tensor:
        """``V [S, T, nu_own]`` -> ``[S, T, nu]`` with the others' controls of :meth:`begin`."""
        S, T, _ = V.shape
        full = self._others[:T].to(V.device, V.dtype).expand(S, T, -1).clone()
        full[..., self._own.to(V.device)] = V
        return full

    def widen_one(self, u: np.ndarray, t: float) -> np.ndarray:
        """One control of this robot ``[nu_own]`` at world time ``t`` -> the world's ``[nu]``."""
        full = self.at(t)
        full[self.own] = u
        return full
