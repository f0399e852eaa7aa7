"""MPPI (thesis Alg. 2): its sample costs, the parts it shares with M3P2I, and the
single-mode planner itself, as a reference and baseline.

Shapes: K samples, T horizon, nu controls.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from .bounds import Box
from .config import MPPIConfig
from .device import Device
from .result import PlanResult
from .sampling import make_noise
from .shift import shift
from .smoothing import Smoothing
from .temperature import finite_costs, softmin_weights


def trajectory_costs(step_costs: Tensor, discount: Tensor) -> Tensor:
    """S_k = Σ_t γ^t c_{k,t} (paper Eq. 4; the caller puts the terminal cost φ in the last column).

    Args:
        step_costs: ``[S, T]`` per-step costs.
        discount: ``[T]`` powers γ^t.

    Returns:
        ``[S]`` total costs.
    """
    return step_costs @ discount


def control_costs(
    mean: Tensor, eps: Tensor, inv_var: Tensor, coef: Tensor | float, keep: Tensor | None = None
) -> Tensor:
    """Importance-sampling control cost  coef · Σ_t (u_tᵀΣ⁻¹u_t + 2u_tᵀΣ⁻¹ε_t)  (thesis Alg. 2
    line 18, thesis Eq. 2.46) with coef = λ/2 · scale and diagonal Σ, over the sampled channels
    only.

    A pinned channel (``keep`` 0) is not sampled: its u is the pinned value, not a choice of the
    noise, and its ε is 0. Charging uᵀΣ⁻¹u there would add the same T·u²/σ² to every sample of
    the mode, which the mode's own weights ignore but the fused weights (paper Eqs. 9-11) do not:
    a mode with suction pinned on would lose all weight whatever its cost.

    Args:
        mean: ``[S, T, nu]`` or ``[T, nu]`` sampling mean u of each sample.
        eps: ``[S, T, nu]`` noise ε = v - u actually applied (after bounds).
        inv_var: ``[nu]`` 1/σ².
        coef: scalar or ``[S]``.
        keep: ``[S, 1, nu]`` 1 on sampled channels, 0 on pinned ones; ``None``: all sampled.

    Returns:
        ``[S]`` costs.
    """
    if keep is not None:
        mean = mean * keep  # u = 0 removes the channel's whole term, 2uᵀΣ⁻¹ε included
    return coef * (mean * (mean + 2.0 * eps) * inv_var).sum(dim=(-2, -1))


class MppiCore:
    """What MPPI and M3P2I build identically from a config: their device, noise scale σ
    ``[nu]``, 1/σ² ``[nu]``, discounts γ^t ``[T]``, bounds, control-cost coefficient, the
    finishing of their means (smoothing, projection, shift) and their sampler."""

    def __init__(
        self, cfg: MPPIConfig, samples: int, dtype: torch.dtype, device: str | torch.device
    ):
        self.cfg = cfg
        self.dev = dev = Device(dtype, device)
        self.sigma = torch.tensor(cfg.noise_sigma, dtype=dtype, device=dev.device)
        self.inv_var = self.sigma.pow(-2)
        self.discount = cfg.gamma ** torch.arange(cfg.horizon, dtype=dtype, device=dev.device)
        self.box = Box(cfg, dtype, dev.device)
        # λ/2 of thesis Alg. 2 line 18 with the *initial* λ: the adapted λ_i would scale the
        # control cost with the temperature meant to temper it, and the gaps (hence λ_i) would
        # grow without end.
        self.control_coef = cfg.lambda_init * (0.5 * cfg.control_cost)
        self.smoothing = Smoothing(cfg, self.box, dtype, dev.device)
        self.make_noise(samples)

    def make_noise(self, samples: int) -> None:
        """A fresh sampler (``cfg.sampling``) for ``samples`` rows."""
        self.noise = make_noise(self.cfg, samples, self.dev.dtype, self.dev.device)

    def zeros(self, *lead: int) -> Tensor:
        """Zero control sequences ``[*lead, T, nu]``."""
        return self.dev.zeros(*lead, self.cfg.horizon, self.cfg.nu)


class MPPI:
    """Plain MPPI, thesis Alg. 2, as a reference and baseline.

    Per iteration: v = g(U + ε) (ε Gaussian or Halton-spline, g = bounds), S_k from the per-step
    costs (paper Eq. 4, plus the control cost of line 18 if enabled), ω = softmin(S, λ) with the
    min-cost shift (lines 25-29), U ← SGF(U + Σ_k ω_k ε_k) with ε the bounded noise (line 33),
    then the shift (lines 36-39). The optional null-action and kept-best samples are the same
    extra rows as in :class:`~.m3p2i.M3P2I`; disable both for the literal algorithm.

    Args:
        cfg: parameters; ``eta_bounds`` and ``alpha_u`` must be the identity choices
            (``None``, 1.0) since thesis Alg. 2 has neither.
        samples: K.
    """

    def __init__(
        self,
        cfg: MPPIConfig,
        samples: int,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
    ):
        if cfg.eta_bounds is not None or cfg.alpha_u != 1.0:
            raise ValueError(
                "MPPI (thesis Alg. 2) has a fixed temperature and full steps: "
                "use eta_bounds=None, alpha_u=1.0, or M3P2I"
            )
        if samples < 1 + cfg.null_action + cfg.keep_best:
            raise ValueError(f"MPPI needs more than {cfg.null_action + cfg.keep_best} samples")
        self.num_samples = samples
        self._p = MppiCore(cfg, samples, dtype, device)
        self.reset()

    def reset(self) -> None:
        """Zero control sequence (clamped into the bounds), fresh random stream."""
        p = self._p
        self._null = p.box.project(p.zeros())  # [T, nu]
        self.U = self._null.clone()  # [T, nu]
        self._best = self._null.clone()  # [T, nu]
        self._v: Tensor | None = None
        p.noise.reset()

    def sample(self) -> Tensor:
        """Returns ``V = g(U + σ·ε)``, ``[K, T, nu]``."""
        p = self._p
        v = p.box.bound(torch.addcmul(self.U, p.noise.draw(), p.sigma))
        if p.cfg.keep_best:
            v[0] = self._best
        if p.cfg.null_action:
            v[-1] = self._null
        self._v = v
        return v

    def update(self, step_costs: Tensor) -> PlanResult:
        """Weights the last :meth:`sample` by its costs and moves U (thesis Alg. 2 lines 18-39);
        returns the plan, then shifts U for the next iteration.

        Args:
            step_costs: ``[K, T]`` per-step costs, the terminal cost in the last column.

        Returns:
            ``U [T, nu]`` before the shift, the lowest-cost sample ``[1, T, nu]`` and the
            weights ω ``[K]`` (as both rows of ``fused [2, K]``).
        """
        p, v = self._p, self._take_samples()  # V: [K, T, nu]
        lam = p.cfg.lambda_init
        step_costs = p.dev.step_costs(step_costs, (self.num_samples, p.cfg.horizon))
        costs = trajectory_costs(step_costs, p.discount)  # paper Eq. 4: S [K]
        eps = v - self.U  # ε = V - U, bounded [K, T, nu]
        if p.cfg.control_cost:  # line 18: + λ/2 (…)
            costs = costs + control_costs(self.U, eps, p.inv_var, p.control_coef)
        # lines 25-29: ρ = min S, η = Σ exp(-(S - ρ)/λ), ω = exp(-(S - ρ)/λ)/η, on the host;
        # a diverged rollout (NaN, ±inf) gets ω = 0
        costs = finite_costs(p.dev.host(costs))
        w, eta, rho = softmin_weights(costs, lam)
        w = p.dev.tensor(w)  # [K]
        u = p.smoothing(self.U + (w[:, None, None] * eps).sum(dim=0))  # line 33: U ← SGF(…)
        finite = bool(eta > 0) and p.dev.finite(u)
        best = v[int(np.argmin(costs))]
        if not finite:  # no finite cost (all weights 0): keep U and the best, flag the result
            u, best = self.U, self._best
        # one mode: its weights are the fused ones, all the weight is its own
        diag = functools.partial(np.array, [1.0, rho, eta, eta, lam, lam], dtype=np.float64)
        result = PlanResult(
            U=u, best=best[None], fused=w.expand(2, -1), finite=finite, make_diag=diag
        )
        self.U, self._best = shift(u), shift(best)  # lines 36-39
        return result

    def command(self, evaluate: Callable[[Tensor], Tensor]) -> PlanResult:
        """sample -> ``evaluate(V) -> [K, T]`` step costs -> update."""
        return self.update(evaluate(self.sample()))

    def _take_samples(self) -> Tensor:
        if self._v is None:
            raise RuntimeError("update() needs a sample() first")
        v, self._v = self._v, None
        return v
