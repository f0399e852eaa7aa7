"""One planner iteration: sample (M3P2I) -> batched MuJoCo rollout -> per-mode costs -> update.

This is the hot loop. Per iteration it does one rollout of all ``[S, T, nu]`` samples through
the rollout backend (``mujoco.rollout``'s pool by default, MuJoCo Warp optionally: see
planner_client/backends/), one objective evaluation per mode on that mode's rows of
``sensordata [S, T, ·]`` (tensor views, no copies), and the M3P2I update; no Python loop over
samples or time steps. Sampling, costs and the update run on the backend's device; only the
plan and the diagnostics come back to the host.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from planner_client.backends import RolloutBackend
from planner_client.backends.mujoco_pool import MujocoPoolBackend
from planner_client.costs import CostTerm, RolloutBatch
from planner_client.mirror import MocapState
from planner_client.mppi import M3P2I, ModeSpec, MPPIConfig, PlanResult
from planner_client.phases import PhaseClock
from planner_client.problem import PlanningProblem
from planner_client.team import TeamRollouts
from planner_client.variants import AGGREGATES, VariantModels


@dataclass
class Iteration:
    result: PlanResult
    modes: list[str]
    plan: np.ndarray  # [T, nu] the fused plan U with discrete channels resolved, or
    # [1, nu] the robot's safe control when there is no plan (fault)
    dominant: str  # the mode with the largest sum of fused weights
    fault: str | None = None  # why there is no plan this iteration (no finite cost); None: a plan
    top_of: Callable[[], tuple[np.ndarray, np.ndarray]] | None = field(default=None, repr=False)

    @property
    def command(self) -> np.ndarray:
        """``[nu]`` the control to apply now: the plan's first step."""
        return self.plan[0]

    @property
    def top(self) -> np.ndarray:
        """``[M, T, 3]`` robot-frame positions along each mode's lowest-cost samples, for a
        viewer. Made when first read, not by the iteration (a tenth of navigation's work
        outside the rollout, for diagnostics only): read it before the next
        :meth:`MotionPlanner.iterate`, which reuses the rollouts' buffers."""
        return self._top[0]

    @property
    def top_modes(self) -> np.ndarray:
        """``[M]`` the mode (index in :attr:`modes`) of each of :attr:`top`'s trajectories."""
        return self._top[1]

    @functools.cached_property
    def _top(self) -> tuple[np.ndarray, np.ndarray]:
        if self.top_of is None:
            return np.zeros((0, 0, 3)), np.zeros(0, dtype=np.int64)
        return self.top_of()


class MotionPlanner:
    """M3P2I over the problem's objectives; the active modes are objective names."""

    def __init__(
        self,
        problem: PlanningProblem,
        cfg: MPPIConfig,
        samples: int,
        modes: list[str],
        nthread: int = 0,
        top_k: int = 5,
        backend: RolloutBackend | None = None,
        variants: VariantModels | None = None,
    ):
        """``backend``: where rollouts run (default: ``mujoco.rollout``'s pool with ``nthread``
        threads on ``problem.model``); the M3P2I state lives on its device. ``variants``: the
        rollouts run in these copies of the model (``planner.model.variants``), which only the
        ``mujoco`` backend can."""
        self.problem = problem
        self.cfg = cfg
        self.samples = samples
        self.top_k = top_k
        self.engine = backend if backend is not None else MujocoPoolBackend(problem.model, nthread)
        self.phases = PhaseClock()  # the iteration's split, with the controller's phases
        self.device = self.engine.device
        self.mppi = M3P2I(
            cfg, [self._mode(m) for m in modes], dtype=torch.float64, device=self.device
        )
        self.modes = list(modes)
        self._shared = self._shared_terms()
        self._read_sensors()
        self._step_costs: torch.Tensor | None = None
        self._generation = 0  # iterations so far (Iteration.top)
        # the planning model's timestep is fixed once built (timing.predict changes it only
        # inside its own block); read through the bindings it costs more than a term
        self._dt = float(problem.model.opt.timestep)
        # one inference-mode context for every iterate(): the decorator builds a new one per call
        self._inference = torch.inference_mode()
        self._last_V: torch.Tensor | None = None  # [S, T, nu] of the last iterate()
        self.variants = variants
        self._variant_rows = 0  # the samples the engine's per-rollout models were set for
        # a team's other robots, along their plans in every rollout (planner_client.team)
        sc = problem.scenario
        self.team = TeamRollouts(sc, problem.model, self._dt, cfg.horizon) if sc.team else None

    def _mode(self, name: str) -> ModeSpec:
        return ModeSpec(name=name, samples=self.samples, fixed=self.problem.objectives[name].fixed)

    def set_modes(self, modes: list[str]) -> None:
        """Change the alternatives (e.g. a new AIP plan); means of kept modes survive."""
        if list(modes) != self.modes:
            self.mppi.set_modes([self._mode(m) for m in modes])
            self.modes = list(modes)
            self._shared = self._shared_terms()
            self._read_sensors()

    def set_samples(self, samples: int) -> None:
        """Roll out ``samples`` per mode from the next iteration on (the anytime planner:
        planner_client.budget); the modes keep their means and temperatures."""
        if samples != self.samples:
            self.samples = samples
            self.mppi.set_modes([self._mode(m) for m in self.modes])

    @property
    def horizon(self) -> int:
        """The steps each sample rolls out now (``planner.horizon`` unless a budget shed some)."""
        return self.mppi.horizon

    def set_horizon(self, horizon: int) -> None:
        """Roll out ``horizon`` steps from the next iteration on (the anytime planner, when its
        fewest samples still overrun the budget); the plans keep their first steps."""
        self.mppi.set_horizon(horizon)

    def prepare_horizons(self, shortest: int) -> None:
        """Make the tables of every horizon from ``shortest`` to the current one now, before
        an anytime planner may shed steps in real time (:meth:`M3P2I.prepare_horizons`)."""
        self.mppi.prepare_horizons(range(shortest, self.horizon))

    def _shared_terms(self) -> list[CostTerm]:
        """The terms of every mode's objective (by :attr:`CostTerm.key`), when there are several
        modes: evaluated once on all S rows instead of once per mode (push and pull share their
        distances and the orientation, the costliest term). A term's value at a row does not
        depend on the other rows, so each mode reads what it would compute itself, bit for bit."""
        if len(self.modes) < 2:
            return []
        keys = [
            {wt.term.key: wt.term for wt in self.problem.objectives[m].terms} for m in self.modes
        ]
        return [term for key, term in keys[0].items() if all(key in k for k in keys[1:])]

    def _read_sensors(self) -> None:
        """Tell the backend which sensors the modes' objectives read, with the robot's position
        (the diagnostics' trajectories) and the problem's extra sensors: the others need not be
        computed in the rollouts."""
        p = self.problem
        modes_read = (r for m in self.modes for r in p.objectives[m].sensors())
        read = {p.robot_pos, *p.extra_sensors, *modes_read}
        self.engine.read_sensors(np.array(sorted(p.model.sensor(r.name).id for r in read)))

    def iterate(self, x0: np.ndarray, mocap: MocapState | None = None) -> Iteration:
        """One iteration from the full physics state ``x0 [nstate]`` and the mocap bodies'
        ``mocap`` state; moving ones go at constant velocity through the rollouts (paper Eq. 22).

        In inference mode: nothing here is differentiated, and skipping autograd's dispatch and
        the version counters of views and in-place writes takes 10-12 % off the iteration's few
        hundred small tensor operations (``no_grad`` alone takes nothing off)."""
        with self._inference:
            return self._iterate(x0, mocap)

    def _iterate(self, x0: np.ndarray, mocap: MocapState | None) -> Iteration:
        V = self.mppi.sample()  # [S, T, nu]
        self.phases.mark("sampling")
        self._last_V = V
        path = None
        if mocap is not None:
            self.engine.set_mocap(mocap.pos, mocap.quat)
            if mocap.moving:
                steps = np.arange(V.shape[1])[:, None, None] * self._dt
                path = mocap.pos[None] + mocap.vel[None] * steps  # [T, nmocap, 3]
        if self.variants is None:
            W = V if self.team is None else self.team.widen(V)  # [S, T, nu of the world]
            sd = self.engine.sensors(x0, W, path)  # [S, T, nsensordata]
            self.phases.mark("rollout")
            self._step_costs = self._costs(sd, V)  # [S, T]
            self.phases.mark("costs")
        else:  # each variant's rollout and costs in turn: one phase
            sd = self._variant_costs(x0, V, path)
            self.phases.mark("rollout")
        result = self.mppi.update(self._step_costs)
        self._generation += 1
        top_of = functools.partial(
            self._top_samples, sd, self.mppi.costs, self.mppi.mode_slices, self._generation
        )
        if self.device.type != "cpu":
            result = _to_host(result)
        self.phases.mark("update")
        dominant = (
            self.modes[0]
            if len(self.modes) == 1
            else self.modes[int(np.argmax(result.mode_weights.numpy()))]
        )
        if not result.finite:
            # No sample had a finite cost: u0 is the previous plan, not an answer to this state.
            return Iteration(
                result=result,
                modes=list(self.modes),
                top_of=top_of,
                plan=self.problem.robot.safe_stop()[None],
                dominant=dominant,
                fault=self._fault(result),
            )
        return Iteration(
            result=result,
            modes=list(self.modes),
            top_of=top_of,
            plan=self._resolve(result.U.numpy(), dominant),
            dominant=dominant,
        )

    def _costs(self, sd: torch.Tensor, V: torch.Tensor) -> torch.Tensor:
        """``[S, T]`` step costs of the modes' objectives on their rows of ``sd [S, T, ·]``
        (the terms every mode shares evaluated once)."""
        columns, dt = self.problem.columns, self._dt
        if len(self.modes) == 1:
            return self.problem.objectives[self.modes[0]](RolloutBatch(sd, V, columns, dt))
        shared = {t.key: t(RolloutBatch(sd, V, columns, dt)) for t in self._shared}
        return torch.cat(
            [
                self.problem.objectives[name](
                    RolloutBatch(sd[rows], V[rows], columns, dt),
                    {k: v[rows] for k, v in shared.items()},
                )
                for name, rows in zip(self.modes, self.mppi.mode_slices)
            ]
        )

    def _variant_costs(
        self, x0: np.ndarray, V: torch.Tensor, path: np.ndarray | None
    ) -> torch.Tensor:
        """The rollouts over the model variants (``planner.model.variants``): sets
        :attr:`_step_costs` ``[S, T]`` and returns the sensordata ``[S, T, ·]`` the diagnostics
        read (with ``spread: all``, the first variant's)."""
        cfg, variants = self.variants.cfg, self.variants
        S = V.shape[0]
        variants.sync()  # the mocap poses just set, the welds of held objects
        if self._variant_rows != S:
            self.engine.set_models(variants.per_rollout(S, cfg.spread))
            self._variant_rows = S
        if cfg.spread != "all":  # split, identified: one model per sample
            sd = self.engine.sensors(x0, V, path)
            self._step_costs = self._costs(sd, V)
            return sd
        sd = self.engine.sensors(x0, V.repeat(cfg.count, 1, 1), path)  # [V·S, T, ·]
        per_variant = torch.stack(
            [self._costs(sd[v * S : (v + 1) * S], V) for v in range(cfg.count)]
        )  # [V, S, T]
        self._step_costs = AGGREGATES[cfg.aggregate](per_variant, cfg.cvar_alpha)
        return sd[:S]

    @torch.inference_mode()
    def _top_samples(
        self, sd: torch.Tensor, costs: np.ndarray, slices: list[slice], generation: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`Iteration.top` and :attr:`Iteration.top_modes` of iteration ``generation``
        from its ``sensordata [S, T, ·]``, total costs ``[S]`` and mode rows: each mode's
        ``top_k`` lowest-cost samples (by the fused weights alone a viewer would see only the
        dominant mode's)."""
        if generation != self._generation:
            raise RuntimeError(
                "Iteration.top read after the next iterate(): the rollouts' "
                "sensor buffer holds that iteration's samples now"
            )
        picks, modes = [], []
        for i, rows in enumerate(slices):
            k = min(self.top_k, rows.stop - rows.start)
            picks.append(np.argsort(costs[rows], kind="stable")[:k] + rows.start)
            modes += [i] * k
        best = torch.from_numpy(np.concatenate(picks)).to(sd.device)
        top = self.problem.columns.take(sd, self.problem.robot_pos).index_select(0, best)
        return top.cpu().numpy(), np.array(modes, dtype=np.int64)

    @property
    def last_samples(self) -> np.ndarray | None:
        """``[S, T, nu]`` controls of the last iteration's rollouts (on the CPU the sampler's
        buffer itself, which the next iteration overwrites; from a GPU a copy, made only when
        asked for: the planner itself never moves them off the device)."""
        return None if self._last_V is None else self._last_V.cpu().numpy()

    def _fault(self, result: PlanResult) -> str:
        """Why ``result`` is no plan, naming the objectives whose costs were not finite."""
        if bool(torch.isfinite(result.mode_costs).any()):
            return "the fused plan is not finite"
        bad = [
            name
            for name, rows in zip(self.modes, self.mppi.mode_slices)
            if not bool(torch.isfinite(self._step_costs[rows]).all())
        ]
        what = f"objectives {bad} returned NaN or inf" if bad else "the summed costs overflowed"
        return (
            f"no finite cost among the {self.mppi.num_samples} samples: {what} "
            f"(diverged rollouts or a faulty cost term)"
        )

    @property
    def dt(self) -> float:
        """Seconds per planned control step (``planner.timestep``, by default the world's)."""
        return self._dt

    def advance(self, steps: float) -> None:
        """The next iteration starts ``steps`` control steps after the last (default one)."""
        self.mppi.advance(steps)

    def _resolve(self, plan: np.ndarray, dominant: str) -> np.ndarray:
        """The plan ``[T, nu]`` with the channels the dominant mode pins (suction on/off,
        gripper) set to its values: a blend of on and off is neither (thesis: the executed
        suction follows the mode with the largest fused weight). Channels only other modes pin
        keep the fused value."""
        fixed = self.problem.objectives[dominant].fixed
        if not fixed:
            return plan
        plan = plan.copy()
        for ch, value in fixed.items():
            plan[:, ch] = value
        return plan

    def close(self) -> None:
        self.engine.close()


def _to_host(result: PlanResult) -> PlanResult:
    """``result`` with its tensors copied to the CPU: the plan and diagnostics the loop sends."""
    return dataclasses.replace(
        result,
        **{
            f.name: getattr(result, f.name).cpu()
            for f in dataclasses.fields(result)
            if isinstance(getattr(result, f.name), torch.Tensor)
        },
    )
