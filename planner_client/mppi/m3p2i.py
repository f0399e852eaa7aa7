"""Multi-Modal MPPI, M3P2I (paper Alg. 3-4, paper Eqs. 4-12).

The planner never sees states or dynamics: each iteration the caller takes the sampled control
sequences ``V: [S, T, nu]`` from :meth:`M3P2I.sample`, rolls them out (batched MuJoCo, or any
model), and hands back per-step costs ``[S, T]`` to :meth:`M3P2I.update`.
:meth:`M3P2I.command` does the three in one call.

Shapes: S samples in all (Σ_i K_i, grouped by mode), T horizon, nu controls, N modes.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import Tensor

from .config import ModeSpec, MPPIConfig
from .mode_rows import ModeLayout
from .mppi import MppiCore, control_costs, trajectory_costs
from .result import PlanResult, diagnostics
from .shift import shift
from .temperature import weigh


class M3P2I:
    """Multi-Modal MPPI (paper Alg. 4) over N modes with their own means, temperatures and costs.

    Per iteration:
      1. :meth:`sample`: mode i draws ``V = g(μ_i + σ·ε)`` for its rows (Halton-spline or Gaussian
         ε), row 0 is its previous best sequence (shifted), its last row the null action, and its
         fixed channels are pinned. Rows are grouped by mode (:attr:`mode_slices`).
      2. :meth:`update` with per-step costs ``[S, T]``: S_k (paper Eq. 4 + optional control
         cost); per mode β_i, η_i, λ_i (paper Eqs. 5-7, paper Alg. 3) and μ_i ← Σ ω_i V (paper
         Eq. 8); fused weights over all S samples (paper Eqs. 9-11, their λ adapted to the same
         η window); u ← (1-α_u)u + α_u Σ ω̃ V (paper Eq. 12); Savitzky-Golay smoothing of u and
         μ_i; projection onto the bounds; shift.

    The N means and the fused plan are one ``[N + 1, T, nu]`` tensor, and the weights of all
    N + 1 rows one ``[N + 1, S]`` matrix (a mode's row is 0 outside its samples), so paper
    Eqs. 8 and 12 are one matrix product ``Σ_k ω_k V_k``, and the smoothing, projection and
    shift one more product and one clamp (:func:`~.smoothing.smooth_shift_matrix`): an
    iteration is a few dozen tensor operations whatever N.

    With one mode, α_u = 1 and no temperature adaptation this is :class:`~.mppi.MPPI` (same
    seed, same samples and weights to rounding): μ_1 and u then follow thesis Alg. 2's
    recursion, which :class:`~.mppi.MPPI` writes as ``U + Σ_k ω_k ε_k``, equal since Σ ω = 1.

    Fixed channels are pinned in every sample of a mode, so μ_i keeps them; the fused u blends the
    modes' values by weight, and the caller takes discrete decisions from ``mode_weights``.

    Args:
        cfg: shared parameters.
        modes: at least one mode; names must be unique.
        dtype, device: of every tensor the planner makes and returns.
    """

    def __init__(
        self,
        cfg: MPPIConfig,
        modes: Sequence[ModeSpec],
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
    ):
        self._p = MppiCore(cfg, sum(m.samples for m in modes), dtype, device)
        self._set_layout(modes)
        self.reset()

    @property
    def modes(self) -> tuple[ModeSpec, ...]:
        """The N modes, in row order."""
        return self._modes

    @property
    def horizon(self) -> int:
        """T, the steps of every sequence (:meth:`set_horizon` changes it)."""
        return self._p.cfg.horizon

    @property
    def num_samples(self) -> int:
        """S = Σ_i K_i."""
        return self._s

    @property
    def mode_slices(self) -> list[slice]:
        """Rows of ``V`` (and of the step costs) owned by each mode, in mode order."""
        return self._layout.slices

    @property
    def means(self) -> Tensor:
        """``[N, T, nu]`` per-mode means μ_i the next :meth:`sample` draws around (already
        shifted)."""
        return self._plans[:-1]

    @property
    def nominal(self) -> Tensor:
        """``[T, nu]`` fused nominal control sequence u carried into the next iteration (already
        shifted)."""
        return self._plans[-1]

    @property
    def costs(self) -> np.ndarray | None:
        """``[S]`` total costs S_k of the last update's samples (paper Eq. 4 with the control
        cost, +inf for diverged rollouts), on the host; ``None`` before the first."""
        return self._costs

    @property
    def temperatures(self) -> np.ndarray:
        """``[N + 1]`` λ of each mode, then of the fused weights, for the next update."""
        return self._lam

    def reset(self) -> None:
        """Zero means and plans (clamped into the bounds), initial temperatures, fresh random
        stream."""
        p, n = self._p, len(self._modes)
        u = p.box.project(p.zeros())  # [T, nu]
        # (μ_1..μ_N and u [N + 1, T, nu], best [N, T, nu]) as the last update left them; what
        # sample() draws around is derived from them
        self._unshifted = (u.expand(n + 1, -1, -1).clone(), u.expand(n, -1, -1).clone())
        self._retime(0.0)
        self._lam = np.full(n + 1, p.cfg.lambda_init)
        self._costs: np.ndarray | None = None
        self._v: Tensor | None = None
        p.noise.reset()

    def set_modes(self, modes: Sequence[ModeSpec]) -> None:
        """Changes the set of modes between iterations.

        A mode whose name persists keeps its mean, best sequence and temperature (its sample
        count and fixed channels may change); a new mode starts from the fused plan u, with
        ``lambda_init``. The fused plan and temperature are kept.
        """
        p = self._p
        old = {m.name: i for i, m in enumerate(self._modes)}
        keep = [old.get(m.name) for m in modes]
        plans, best = self._unshifted
        u = plans[-1]
        plans = torch.stack([plans[i] if i is not None else u for i in keep] + [u])
        best = torch.stack([best[i] if i is not None else u for i in keep])
        lam = np.array(
            [self._lam[i] if i is not None else p.cfg.lambda_init for i in keep] + [self._lam[-1]]
        )
        previous = self._s
        self._set_layout(modes)  # validates before anything changes
        self._unshifted = (plans, best)
        self._retime(self._steps)
        self._lam = lam
        if self._s != previous:
            p.make_noise(self._s)
        self._v, self._costs = None, None

    def set_horizon(self, horizon: int) -> None:
        """Plans ``horizon`` steps from the next iteration on (the anytime planner sheds steps
        when even its fewest samples overrun its budget, planner_client.budget). The means, plan
        and best sequences keep their first steps, or grow by holding their last one (as a shift
        does); modes and temperatures are kept; the sampler starts afresh for the new length.

        Raises ValueError (from :class:`MPPIConfig`) for a horizon the config cannot take, e.g.
        below ``savgol_window``."""
        p = self._p
        if horizon == p.cfg.horizon:
            return
        cfg = dataclasses.replace(p.cfg, horizon=horizon)  # validates
        self._p = MppiCore(cfg, self._s, p.dev.dtype, p.dev.device)
        self._unshifted = tuple(_resized(x, horizon) for x in self._unshifted)
        self._set_layout(self._modes)
        self._retime(self._steps)
        self._v, self._costs = None, None

    def prepare_horizons(self, horizons: Sequence[int]) -> None:
        """Computes now the sampler's and the smoothing's tables for each of ``horizons`` (they
        are cached on disk, planner_client/mppi/cache.py), so that :meth:`set_horizon` reads them
        instead of importing SciPy in the middle of a real-time episode."""
        p = self._p
        for horizon in horizons:
            MppiCore(
                dataclasses.replace(p.cfg, horizon=horizon), self._s, p.dev.dtype, p.dev.device
            )

    def advance(self, steps: float) -> None:
        """Re-times the warm start: the next iteration starts ``steps`` control steps (may be
        fractional, or less than one) after the last one, where :meth:`update` assumed one.

        A planner slower than the world calls it with the world time that really passed
        (hydrax's re-interpolation of the plan at the new state's time), so that the means
        are read at the times they were planned for.
        """
        self._retime(steps)

    def _retime(self, steps: float) -> None:
        """Means, plan and best sequences for the next iteration: the last update's, ``steps``
        later (always from the unshifted plans: a shift of 0.3 must not lose step 0)."""
        self._steps = steps
        self._plans, self._best = (shift(x, steps) for x in self._unshifted)

    def sample(self) -> Tensor:
        """Returns the control sequences to roll out, ``[S, T, nu]``."""
        p, lay = self._p, self._layout
        # one kernel reads the sampler's transposed buffer, scales and shifts it (row_mode < N
        # picks each row's mode mean out of the plans; one mode's broadcasts)
        one = len(self._modes) == 1
        mean = self._plans[0] if one else self._plans.index_select(0, lay.row_mode)
        v = torch.addcmul(mean, p.noise.draw(), p.sigma)
        if p.box.squash:
            p.box.bound(v)
        if p.cfg.keep_best:
            v.index_copy_(0, lay.first, self._best)
        if p.cfg.null_action:
            v.index_copy_(0, lay.last, lay.null)
        if lay.clamp is not None:
            # bounds and pins in one kernel; the best and null rows are inside both already
            torch.clamp(v, *lay.clamp, out=v)
        elif lay.pin_keep is not None:
            v.mul_(lay.pin_keep).add_(lay.pin_value)
        self._v = v
        return v

    def update(self, step_costs: Tensor) -> PlanResult:
        """Weights the last :meth:`sample` by its costs and moves the means and the plan
        (paper Alg. 4, Eqs. 4-12); returns the plan, then shifts all for the next iteration.

        Args:
            step_costs: ``[S, T]`` per-step costs, rows grouped by mode as sampled, the terminal
                cost φ in the last column.

        Returns:
            The fused plan ``U [T, nu]`` before the shift, each mode's lowest-cost sample
            ``best [N, T, nu]`` and the weights ``fused [N + 1, S]`` (ω_1..ω_N, then ω̃);
            ``finite`` is ``False`` when no sample had a finite cost.
        """
        p, lay, n = self._p, self._layout, len(self._modes)
        v = self._take_samples()  # V: [S, T, nu]
        S, T, nu = v.shape
        costs = trajectory_costs(p.dev.step_costs(step_costs, (S, T)), p.discount)  # Eq. 4: [S]
        if p.cfg.control_cost:
            # thesis Alg. 2 line 18 for V_k's noise about its own mode's mean μ_i(k)
            mu = self._plans.index_select(0, lay.row_mode)  # [S, T, nu]
            costs = costs + control_costs(mu, v - mu, p.inv_var, p.control_coef, lay.pin_keep)
        # Each mode i over its rows κ(i) (Alg. 4 lines 18-20) and, fused, all S (line 24), on
        # the host (few numbers: NumPy beats torch's dispatch):
        #   Eqs. 7, 11   β = min_k S_k
        #   Alg. 3       λ re-tuned until η lies in [η_l, η_u] (when eta_bounds is set)
        #   Eqs. 6, 10   η = Σ_k exp(-(S_k - β)/λ)
        #   Eqs. 5, 9    ω_k = exp(-(S_k - β)/λ)/η; a diverged rollout (NaN, ±inf) gets 0
        wt = weigh(p.dev.host(costs), lay.slices, self._lam, p.cfg.eta_bounds, p.cfg.adapt_iters)
        self._lam, self._costs = wt.lam, wt.costs
        w = p.dev.tensor(wt.w)  # [N + 1, S]
        # Eq. 8: μ_i ← Σ_k ω_i(k) V_k, and Eq. 12's Σ_k ω̃_k V_k, in one product (a mode's
        # row of w is 0 outside its samples)
        means = w @ v.reshape(S, T * nu)  # [N + 1, T·nu]
        if p.cfg.alpha_u != 1.0:  # Eq. 12: α_u step
            means[n] = torch.lerp(self._plans[n].reshape(-1), means[n], p.cfg.alpha_u)
        # thesis Alg. 2 line 33: SGF and projection onto the bounds of μ_1..μ_N and u; in
        # the same product, their shift for the next iteration (paper Alg. 4 line 29)
        plans, shifted = p.smoothing.and_shift(means)  # [N + 1, T, nu] each
        best = v.index_select(0, p.dev.rows(wt.best))  # [N, T, nu]
        # a row without a finite cost (a mode whose rollouts all diverged, or all S) keeps
        # its λ, mean and best sequence; the fused row its plan, which is then flagged
        alive = wt.eta > 0  # [N + 1]
        alive[n] &= p.dev.finite_row(plans, n)
        plans, best = self._commit(plans, shifted, best, alive)
        return PlanResult(
            U=plans[n],
            best=best,
            fused=w,
            finite=bool(alive[n]),
            make_diag=functools.partial(diagnostics, wt, lay.starts),
        )

    def _commit(
        self, plans: Tensor, shifted: Tensor, best: Tensor, alive: np.ndarray
    ) -> tuple[Tensor, Tensor]:
        """Keeps an update's means and plan ``plans [N + 1, T, nu]`` (``shifted``: the same a
        step later) and best sequences ``best [N, T, nu]`` for the next iteration; a row not
        ``alive [N + 1]`` keeps its previous ones. Returns the kept plans and best sequences."""
        if alive.all():
            self._unshifted = (plans, best)
            self._steps = 1.0
            self._plans, self._best = shifted, shift(best)
            return plans, best
        keep = torch.from_numpy(alive).to(self._p.dev.device)[:, None, None]
        plans = torch.where(keep, plans, self._plans)
        best = torch.where(keep[: len(self._modes)], best, self._best)
        self._unshifted = (plans, best)
        self._retime(1.0)
        return plans, best

    def command(self, evaluate: Callable[[Tensor], Tensor]) -> PlanResult:
        """sample -> ``evaluate(V) -> [S, T]`` step costs -> update."""
        return self.update(evaluate(self.sample()))

    def _take_samples(self) -> Tensor:
        if self._v is None:
            raise RuntimeError("update() needs a sample() first")
        v, self._v = self._v, None
        return v

    def _set_layout(self, modes: Sequence[ModeSpec]) -> None:
        """Validates ``modes`` and builds their row layout, pins and null actions."""
        p, modes = self._p, tuple(modes)
        self._layout = ModeLayout.build(modes, p.cfg, p.box, p.dev)
        self._modes = modes
        self._s = sum(m.samples for m in modes)


def _resized(seq: Tensor, horizon: int) -> Tensor:
    """``seq [..., T, nu]`` cut to its first ``horizon`` steps, or extended holding its last."""
    steps = seq.shape[-2]
    if horizon <= steps:
        return seq[..., :horizon, :].clone()
    tail = seq[..., -1:, :].expand(*seq.shape[:-2], horizon - steps, seq.shape[-1])
    return torch.cat([seq, tail], dim=-2)
