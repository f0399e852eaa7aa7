"""MPPI (thesis Alg. 2) and Multi-Modal MPPI, M3P2I (paper Alg. 3-4, paper Eqs. 4-12).

The planners never see states or dynamics: each iteration the caller takes the sampled control
sequences ``V: [S, T, nu]`` from :meth:`sample`, rolls them out (batched MuJoCo, or any model), and
hands back per-step costs ``[S, T]`` to :meth:`update`. :meth:`command` does the three in one call.

Shapes: S samples in all (M3P2I: Σ_i K_i, grouped by mode), T horizon, nu controls, N modes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from .config import MPPIConfig, ModeSpec
from .sampling import make_noise
from .smoothing import savgol_matrix, smooth
from .temperature import Weights, finite_costs, softmin_weights, weigh


@dataclass(frozen=True)
class PlanResult:
    """Outcome of one planner iteration (before the warm-start shift).

    The per-mode figures live in one host array, :attr:`diag`, read through properties: made
    from the update's host weighting when first read (a single mode's loop reads them for a
    viewer only; several modes' reads the mode weights to pick the dominant one), so an
    iteration nobody inspects pays neither its three calls nor a dozen tensor views.

    Attributes:
        U: ``[T, nu]`` fused, smoothed, bounded control sequence (paper Eq. 12).
        best: ``[N, T, nu]`` lowest-cost sample sequence of each mode.
        fused: ``[N + 1, S]`` weights of each mode's problem (a row is 0 outside the mode's
            samples) and, last, the fused weights ω̃ (paper Eq. 9).
        make_diag: makes :attr:`diag`'s values, a float64 host array ``[4N + 2]``.
        finite: ``False`` when no sample had a finite cost (every rollout diverged, or the
            objective returned NaN/inf) or the fused plan is not finite. All weights are then 0
            and ``U`` is the previous plan, no answer to the current costs: the caller should
            not send it but fall back to the robot's safe control.
    """

    U: Tensor
    best: Tensor
    fused: Tensor
    finite: bool
    make_diag: Callable[[], np.ndarray] = field(repr=False, compare=False)

    @functools.cached_property
    def diag(self) -> Tensor:
        """``[4N + 2]`` float64 on the CPU whatever the planner's device: mode weights ``[N]``,
        mode costs ``[N]``, η ``[N + 1]`` and λ ``[N + 1]`` (each mode's, then the fused
        one's); see the properties."""
        return torch.from_numpy(self.make_diag())

    @property
    def u0(self) -> Tensor:
        """``[nu]`` control to apply now (``U[0]``)."""
        return self.U[0]

    @property
    def num_modes(self) -> int:
        """N."""
        return self.best.shape[0]

    @property
    def weights(self) -> Tensor:
        """``[S]`` fused sample weights ω̃ (paper Eq. 9)."""
        return self.fused[-1]

    @property
    def mode_weights(self) -> Tensor:
        """``[N]`` fused weight mass of each mode's samples (sums to 1); the dominant mode
        decides discrete choices such as suction on/off."""
        return self.diag[:self.num_modes]

    @property
    def mode_costs(self) -> Tensor:
        """``[N]`` lowest total cost among each mode's samples (β_i, paper Eq. 7)."""
        n = self.num_modes
        return self.diag[n:2 * n]

    @property
    def etas(self) -> Tensor:
        """``[N]`` per-mode normalisers η_i (paper Eq. 6), roughly the number of samples that
        count."""
        n = self.num_modes
        return self.diag[2 * n:3 * n]

    @property
    def fused_eta(self) -> Tensor:
        """``[]`` normaliser η of the fused weights (paper Eq. 10)."""
        return self.diag[3 * self.num_modes]

    @property
    def lambdas(self) -> Tensor:
        """``[N]`` per-mode temperatures λ_i used this iteration."""
        n = self.num_modes
        return self.diag[3 * n + 1:4 * n + 1]

    @property
    def fused_lambda(self) -> Tensor:
        """``[]`` temperature λ of the fused weights."""
        return self.diag[4 * self.num_modes + 1]


def _diagnostics(wt: Weights, starts: list[int]) -> np.ndarray:
    """:attr:`PlanResult.diag` of an update's weighting ``wt`` of N modes whose rows start at
    ``starts [N]``: each mode's share of the fused weights, β_i, η and λ (the modes', then
    the fused one's)."""
    n = len(starts)
    return np.concatenate([np.add.reduceat(wt.w[n], starts), wt.beta[:n], wt.eta, wt.lam])


def trajectory_costs(step_costs: Tensor, discount: Tensor) -> Tensor:
    """S_k = Σ_t γ^t c_{k,t} (paper Eq. 4; the caller puts the terminal cost φ in the last column).

    Args:
        step_costs: ``[S, T]`` per-step costs.
        discount: ``[T]`` powers γ^t.

    Returns:
        ``[S]`` total costs.
    """
    return step_costs @ discount


def control_costs(mean: Tensor, eps: Tensor, inv_var: Tensor, coef: Tensor | float,
                  keep: Tensor | None = None) -> Tensor:
    """Importance-sampling control cost  coef · Σ_t (u_tᵀΣ⁻¹u_t + 2u_tᵀΣ⁻¹ε_t)  (thesis Alg. 2 line 18,
    thesis Eq. 2.46) with coef = λ/2 · scale and diagonal Σ, over the sampled channels only.

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
        mean = mean * keep      # u = 0 removes the channel's whole term, 2uᵀΣ⁻¹ε included
    return coef * (mean * (mean + 2.0 * eps) * inv_var).sum(dim=(-2, -1))


def shift(seq: Tensor, steps: float = 1.0) -> Tensor:
    """Warm start ``steps`` control steps later, ``[..., T, nu] -> [..., T, nu]``.

    New step t is the old sequence at t + steps: linearly interpolated between steps for a
    fractional shift, the last step repeated past the end and the first held before the start
    (a negative shift). Repeating (as the thesis code does) keeps a constant command going at the
    end of the horizon; a zero would brake velocity-controlled robots in every fresh plan tail.
    An integer shift is an exact copy of the kept steps.
    """
    horizon = seq.shape[-2]
    whole = math.floor(steps)
    frac = steps - whole
    lo_idx, hi_idx = _shift_index(horizon, whole, seq.device)
    lo = seq.index_select(-2, lo_idx)
    if frac == 0.0:
        return lo
    return torch.lerp(lo, seq.index_select(-2, hi_idx), frac)


@functools.lru_cache(maxsize=64)
def _shift_index(horizon: int, whole: int, device: torch.device) -> tuple[Tensor, Tensor]:
    """``[T]`` rows ``t + whole`` and ``t + whole + 1`` clamped into the horizon, for
    :func:`shift`: made once, as the planner shifts three sequences by one step every iteration
    (read-only: ``index_select`` never writes its index)."""
    idx = torch.arange(horizon, device=device) + whole
    return idx.clamp(0, horizon - 1), (idx + 1).clamp(0, horizon - 1)


def smooth_shift_matrix(savgol: Tensor | None, horizon: int, nu: int, dtype: torch.dtype,
                        device: torch.device) -> Tensor:
    """``[T·nu, 2·T·nu]``: a mean sequence flattened to ``[T·nu]`` (step-major) times it is the
    sequence smoothed by ``savgol [T, T]`` (none: unchanged), then that smoothed sequence
    shifted by one step as :func:`shift` does (the last step repeated). The update smooths its
    new means and shifts them for the next iteration in this one product instead of a batched
    product and an index per sequence."""
    eye = torch.eye(horizon, dtype=dtype, device=device)
    smooth_m = eye if savgol is None else savgol                           # [T, T]
    lo_idx, _ = _shift_index(horizon, 1, device)
    steps = torch.cat([smooth_m, smooth_m.index_select(0, lo_idx)])       # [2T, T]
    return torch.kron(steps, torch.eye(nu, dtype=dtype, device=device)).T.contiguous()


class _Box:
    """Control bounds of a config: sample bounding (clamp or squash) and projection."""

    def __init__(self, cfg: MPPIConfig, dtype: torch.dtype, device: torch.device):
        self.active = cfg.u_min is not None
        self.squash = cfg.bound == "squash"
        if self.active:
            self.lo = torch.tensor(cfg.u_min, dtype=dtype, device=device)
            self.hi = torch.tensor(cfg.u_max, dtype=dtype, device=device)
            self.mid = 0.5 * (self.hi + self.lo)
            self.half = 0.5 * (self.hi - self.lo)

    def bound(self, v: Tensor) -> Tensor:
        """Brings samples ``[..., nu]`` into the box, in place."""
        if not self.active:
            return v
        if self.squash:
            return v.sub_(self.mid).div_(self.half).tanh_().mul_(self.half).add_(self.mid)
        return torch.clamp(v, self.lo, self.hi, out=v)

    def project(self, v: Tensor) -> Tensor:
        """Clamps means ``[..., nu]`` (smoothing can overshoot a bound)."""
        return torch.clamp(v, self.lo, self.hi) if self.active else v


class _Common:
    """What MPPI and M3P2I build identically from a config."""

    def __init__(self, cfg: MPPIConfig, samples: int, dtype: torch.dtype, device):
        self.cfg = cfg
        self.dtype = dtype
        self.device = torch.device(device)
        t = cfg.horizon
        self.sigma = torch.tensor(cfg.noise_sigma, dtype=dtype, device=self.device)
        self.inv_var = self.sigma.pow(-2)
        self.discount = cfg.gamma ** torch.arange(t, dtype=dtype, device=self.device)
        self.box = _Box(cfg, dtype, self.device)
        # λ/2 of thesis Alg. 2 line 18 with the *initial* λ: the adapted λ_i would scale the control cost
        # with the temperature meant to temper it, and the gaps (hence λ_i) would grow without end.
        self.control_coef = cfg.lambda_init * (0.5 * cfg.control_cost)
        self.savgol = (torch.as_tensor(savgol_matrix(t, cfg.savgol_window, cfg.savgol_order),
                                       dtype=dtype, device=self.device)
                       if cfg.savgol_window else None)
        self.smooth_shift = smooth_shift_matrix(self.savgol, t, cfg.nu, dtype, self.device)
        if self.box.active:
            self.flat_lo, self.flat_hi = self.box.lo.repeat(2 * t), self.box.hi.repeat(2 * t)
        self.make_noise(samples)

    def make_noise(self, samples: int) -> None:
        self.noise = make_noise(self.cfg, samples, self.dtype, self.device)

    def tensor(self, x: np.ndarray) -> Tensor:
        """A host array of the weighting as a tensor of the planner's dtype and device; on the
        CPU in float64 the same memory (``from_numpy`` takes a microsecond, ``as_tensor`` with
        a dtype and device nine)."""
        if self.device.type == "cpu" and x.dtype == np.float64 and self.dtype == torch.float64:
            return torch.from_numpy(x)
        return torch.as_tensor(x, dtype=self.dtype, device=self.device)

    def host(self, x: Tensor) -> np.ndarray:
        """``x`` on the host as NumPy; on the CPU the same memory, without ``cpu()``'s call."""
        return x.numpy() if self.device.type == "cpu" else x.cpu().numpy()

    def rows(self, x: np.ndarray) -> Tensor:
        """Host row indices ``x`` (int64) as an index tensor on the planner's device."""
        t = torch.from_numpy(x)
        return t if self.device.type == "cpu" else t.to(self.device)

    def finite(self, x: Tensor) -> bool:
        """Whether ``x`` holds no NaN or inf (its sum is finite); on the CPU summed by NumPy
        over the same memory (a third of torch's select, sum and transfer after a rollout)."""
        if self.device.type == "cpu":
            return math.isfinite(x.numpy().sum())
        return math.isfinite(float(x.sum()))

    def finite_row(self, x: Tensor, i: int) -> bool:
        """:meth:`finite` of ``x[i]``, on the CPU without torch's select."""
        if self.device.type == "cpu":
            return math.isfinite(x.numpy()[i].sum())
        return math.isfinite(float(x[i].sum()))

    def zeros(self, *lead: int) -> Tensor:
        return torch.zeros(*lead, self.cfg.horizon, self.cfg.nu, dtype=self.dtype,
                           device=self.device)

    def finish_mean(self, u: Tensor) -> Tensor:
        """SGF then projection onto the bounds, ``[..., T, nu]``."""
        if self.savgol is not None:
            u = smooth(self.savgol, u)
        return self.box.project(u)

    def finish_and_shift(self, flat: Tensor) -> tuple[Tensor, Tensor]:
        """:meth:`finish_mean` of flat means ``[M, T·nu]``, ``[M, T, nu]``, and the same
        shifted by one step (:func:`shift`): one product with :attr:`smooth_shift` and one
        clamp (the projection commutes with a whole-step shift, a selection of steps)."""
        both = flat @ self.smooth_shift
        if self.box.active:
            torch.clamp(both, self.flat_lo, self.flat_hi, out=both)
        return both.view(flat.shape[0], 2, self.cfg.horizon, self.cfg.nu).unbind(1)

    def check_costs(self, step_costs: Tensor, samples: int) -> Tensor:
        shape = (samples, self.cfg.horizon)
        if tuple(step_costs.shape) != shape:
            raise ValueError(f"step_costs must have shape {shape} [S, T], got {tuple(step_costs.shape)}")
        if step_costs.dtype == self.dtype and step_costs.device == self.device:
            return step_costs
        return step_costs.to(dtype=self.dtype, device=self.device)


class MPPI:
    """Plain MPPI, thesis Alg. 2, as a reference and baseline.

    Per iteration: v = g(U + ε) (ε Gaussian or Halton-spline, g = bounds), S_k from the per-step
    costs (paper Eq. 4, plus the control cost of line 18 if enabled), ω = softmin(S, λ) with the
    min-cost shift (lines 25-29), U ← SGF(U + Σ_k ω_k ε_k) with ε the bounded noise (line 33),
    then the shift (lines 36-39). The optional null-action and kept-best samples are the same
    extra rows as in :class:`M3P2I`; disable both for the literal algorithm.

    Args:
        cfg: parameters; ``eta_bounds`` and ``alpha_u`` must be the identity choices
            (``None``, 1.0) since thesis Alg. 2 has neither.
        samples: K.
    """

    def __init__(self, cfg: MPPIConfig, samples: int, dtype: torch.dtype = torch.float64,
                 device: str | torch.device = "cpu"):
        if cfg.eta_bounds is not None or cfg.alpha_u != 1.0:
            raise ValueError("MPPI (thesis Alg. 2) has a fixed temperature and full steps: "
                             "use eta_bounds=None, alpha_u=1.0, or M3P2I")
        if samples < 1 + cfg.null_action + cfg.keep_best:
            raise ValueError(f"MPPI needs more than {cfg.null_action + cfg.keep_best} samples")
        self.num_samples = samples
        self._c = _Common(cfg, samples, dtype, device)
        self.reset()

    def reset(self) -> None:
        """Zero control sequence (clamped into the bounds), fresh random stream."""
        c = self._c
        self._null = c.box.project(c.zeros())    # [T, nu]
        self.U = self._null.clone()              # [T, nu]
        self._best = self._null.clone()          # [T, nu]
        self._v: Tensor | None = None
        c.noise.reset()

    def sample(self) -> Tensor:
        """Returns ``V = g(U + σ·ε)``, ``[K, T, nu]``."""
        c = self._c
        v = c.box.bound(torch.addcmul(self.U, c.noise.draw(), c.sigma))
        if c.cfg.keep_best:
            v[0] = self._best
        if c.cfg.null_action:
            v[-1] = self._null
        self._v = v
        return v

    def update(self, step_costs: Tensor) -> PlanResult:
        """Weights the last :meth:`sample` by ``step_costs: [K, T]``; returns the plan, then shifts."""
        c, v = self._c, self._take_samples()
        lam = c.cfg.lambda_init
        costs = trajectory_costs(c.check_costs(step_costs, self.num_samples), c.discount)
        eps = v - self.U
        if c.cfg.control_cost:
            costs = costs + control_costs(self.U, eps, c.inv_var, c.control_coef)
        costs = finite_costs(c.host(costs))
        w, eta, rho = softmin_weights(costs, lam)
        w = c.tensor(w)
        u = c.finish_mean(self.U + (w[:, None, None] * eps).sum(dim=0))
        finite = bool(eta > 0) and c.finite(u)
        best = v[int(np.argmin(costs))]
        if not finite:      # no finite cost (all weights 0): keep U and the best, flag the result
            u, best = self.U, self._best
        # one mode: its weights are the fused ones, all the weight is its own
        diag = functools.partial(np.array, [1.0, rho, eta, eta, lam, lam], dtype=np.float64)
        result = PlanResult(U=u, best=best[None], fused=w.expand(2, -1), finite=finite,
                            make_diag=diag)
        self.U, self._best = shift(u), shift(best)
        return result

    def command(self, evaluate: Callable[[Tensor], Tensor]) -> PlanResult:
        """sample -> ``evaluate(V) -> [K, T]`` step costs -> update."""
        return self.update(evaluate(self.sample()))

    def _take_samples(self) -> Tensor:
        if self._v is None:
            raise RuntimeError("update() needs a sample() first")
        v, self._v = self._v, None
        return v


@dataclass(frozen=True)
class _Layout:
    """Where N modes' samples sit in the rows of ``[S]``: grouped by mode, in mode order."""

    slices: list[slice]  # [N] rows of each mode
    starts: list[int]    # [N] first row of each mode (slices' starts)
    row_mode: Tensor     # [S] mode of each sample row
    first: Tensor        # [N] first row of each mode
    last: Tensor         # [N] last row of each mode

    @staticmethod
    def build(counts: Sequence[int], device: torch.device) -> _Layout:
        starts = np.cumsum([0, *counts])[:-1]
        k = torch.tensor(counts, device=device)
        first = torch.as_tensor(starts, device=device)
        return _Layout(slices=[slice(int(a), int(a) + n) for a, n in zip(starts, counts)],
                       starts=[int(a) for a in starts],
                       row_mode=torch.repeat_interleave(torch.arange(len(counts), device=device), k),
                       first=first, last=first + k - 1)


class M3P2I:
    """Multi-Modal MPPI (paper Alg. 4) over N modes with their own means, temperatures and costs.

    Per iteration:
      1. :meth:`sample`: mode i draws ``V = g(μ_i + σ·ε)`` for its rows (Halton-spline or Gaussian
         ε), row 0 is its previous best sequence (shifted), its last row the null action, and its
         fixed channels are pinned. Rows are grouped by mode (:attr:`mode_slices`).
      2. :meth:`update` with per-step costs ``[S, T]``: S_k (paper Eq. 4 + optional control cost);
         per mode β_i, η_i, λ_i (paper Eqs. 5-7, paper Alg. 3) and μ_i ← Σ ω_i V (paper Eq. 8); fused weights over
         all S samples (paper Eqs. 9-11, their λ adapted to the same η window); u ← (1-α_u)u + α_u Σ ω̃ V
         (paper Eq. 12); Savitzky-Golay smoothing of u and μ_i; projection onto the bounds; shift.

    The N means and the fused plan are one ``[N + 1, T, nu]`` tensor, and the weights of all
    N + 1 rows one ``[N + 1, S]`` matrix (a mode's row is 0 outside its samples), so paper
    Eqs. 8 and 12 are one matrix product ``Σ_k ω_k V_k``, and the smoothing, projection and
    shift one more product and one clamp (:func:`smooth_shift_matrix`): an iteration is a few
    dozen tensor operations whatever N.

    With one mode, α_u = 1 and no temperature adaptation this is :class:`MPPI` (same seed, same
    samples and weights to rounding): μ_1 and u then follow thesis Alg. 2's recursion, which
    :class:`MPPI` writes as ``U + Σ_k ω_k ε_k``, equal since Σ ω = 1.

    Fixed channels are pinned in every sample of a mode, so μ_i keeps them; the fused u blends the
    modes' values by weight, and the caller takes discrete decisions from ``mode_weights``.

    Args:
        cfg: shared parameters.
        modes: at least one mode; names must be unique.
        dtype, device: of every tensor the planner makes and returns.
    """

    def __init__(self, cfg: MPPIConfig, modes: Sequence[ModeSpec],
                 dtype: torch.dtype = torch.float64, device: str | torch.device = "cpu"):
        self._c = _Common(cfg, sum(m.samples for m in modes), dtype, device)
        self._set_layout(modes)
        self.reset()

    @property
    def modes(self) -> tuple[ModeSpec, ...]:
        return self._modes

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
        """``[N, T, nu]`` per-mode means μ_i the next :meth:`sample` draws around (already shifted)."""
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
        c, n = self._c, len(self._modes)
        u = c.box.project(c.zeros())                            # [T, nu]
        # (μ_1..μ_N and u [N + 1, T, nu], best [N, T, nu]) as the last update left them; what
        # sample() draws around is derived from them
        self._unshifted = (u.expand(n + 1, -1, -1).clone(), u.expand(n, -1, -1).clone())
        self._retime(0.0)
        self._lam = np.full(n + 1, c.cfg.lambda_init)
        self._costs: np.ndarray | None = None
        self._v: Tensor | None = None
        c.noise.reset()

    def set_modes(self, modes: Sequence[ModeSpec]) -> None:
        """Changes the set of modes between iterations.

        A mode whose name persists keeps its mean, best sequence and temperature (its sample
        count and fixed channels may change); a new mode starts from the fused plan u, with
        ``lambda_init``. The fused plan and temperature are kept.
        """
        c = self._c
        old = {m.name: i for i, m in enumerate(self._modes)}
        keep = [old.get(m.name) for m in modes]
        plans, best = self._unshifted
        u = plans[-1]
        plans = torch.stack([plans[i] if i is not None else u for i in keep] + [u])
        best = torch.stack([best[i] if i is not None else u for i in keep])
        lam = np.array([self._lam[i] if i is not None else c.cfg.lambda_init for i in keep]
                       + [self._lam[-1]])
        previous = self._s
        self._set_layout(modes)          # validates before anything changes
        self._unshifted = (plans, best)
        self._retime(self._steps)
        self._lam = lam
        if self._s != previous:
            c.make_noise(self._s)
        self._v, self._costs = None, None

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
        c, lay = self._c, self._layout
        # one kernel reads the sampler's transposed buffer, scales and shifts it (row_mode < N
        # picks each row's mode mean out of the plans; one mode's broadcasts)
        mean = self._plans[0] if len(self._modes) == 1 else self._plans.index_select(0, lay.row_mode)
        v = torch.addcmul(mean, c.noise.draw(), c.sigma)
        if c.box.squash:
            c.box.bound(v)
        if c.cfg.keep_best:
            v.index_copy_(0, lay.first, self._best)
        if c.cfg.null_action:
            v.index_copy_(0, lay.last, self._null)
        if self._clamp is not None:
            # bounds and pins in one kernel; the best and null rows are inside both already
            torch.clamp(v, *self._clamp, out=v)
        elif self._pin_keep is not None:
            v.mul_(self._pin_keep).add_(self._pin_value)
        self._v = v
        return v

    def update(self, step_costs: Tensor) -> PlanResult:
        """Weights the last :meth:`sample` by ``step_costs: [S, T]``; returns the plan, then shifts."""
        c, lay, n = self._c, self._layout, len(self._modes)
        if self._v is None:
            raise RuntimeError("update() needs a sample() first")
        v, self._v = self._v, None
        costs = trajectory_costs(c.check_costs(step_costs, self._s), c.discount)
        if c.cfg.control_cost:
            mu_rows = self._plans.index_select(0, lay.row_mode)
            costs = costs + control_costs(mu_rows, v - mu_rows, c.inv_var, c.control_coef,
                                          self._pin_keep)
        # Per-mode and fused weights and temperatures (paper Eqs. 5-7, 9-11, Alg. 3) on the
        # host. Diverged rollouts get zero weight; a row with no finite cost at all (a mode
        # whose rollouts all diverged, or all S of them) keeps λ, its mean and its best sequence,
        # and, for the fused row, the plan (then flagged: ``finite``).
        wt = weigh(c.host(costs), lay.slices, self._lam,
                   c.cfg.eta_bounds, c.cfg.adapt_iters)
        self._lam, self._costs = wt.lam, wt.costs
        w = c.tensor(wt.w)                                             # [N + 1, S]

        # μ_i ← Σ ω_i V (paper Eq. 8) and Σ ω̃ V (paper Eq. 12) in one product; then u's step
        # α_u; then every mean smoothed, projected and, for the next iteration, shifted
        S, T, nu = v.shape
        flat = w @ v.reshape(S, T * nu)                                # [N + 1, T·nu]
        if c.cfg.alpha_u != 1.0:
            flat[n] = torch.lerp(self._plans[n].reshape(-1), flat[n], c.cfg.alpha_u)
        plans, shifted = c.finish_and_shift(flat)                      # [N + 1, T, nu] each
        best = v.index_select(0, c.rows(wt.best))
        alive = wt.eta > 0                                             # [N + 1]
        alive[n] &= c.finite_row(plans, n)
        finite = bool(alive[n])
        if alive.all():
            self._unshifted = (plans, best)
            self._steps = 1.0
            self._plans, self._best = shifted, shift(best)
        else:
            keep = torch.from_numpy(alive).to(c.device)[:, None, None]
            plans = torch.where(keep, plans, self._plans)
            best = torch.where(keep[:n], best, self._best)
            self._unshifted = (plans, best)
            self._retime(1.0)
        return PlanResult(U=plans[n], best=best, fused=w, finite=finite,
                          make_diag=functools.partial(_diagnostics, wt, lay.starts))

    def command(self, evaluate: Callable[[Tensor], Tensor]) -> PlanResult:
        """sample -> ``evaluate(V) -> [S, T]`` step costs -> update."""
        return self.update(evaluate(self.sample()))

    def _set_layout(self, modes: Sequence[ModeSpec]) -> None:
        """Validates ``modes`` and builds their row layout, pins and null actions."""
        c = self._c
        cfg = c.cfg
        modes = tuple(modes)
        if not modes:
            raise ValueError("M3P2I needs at least one mode")
        if len({m.name for m in modes}) != len(modes):
            raise ValueError(f"mode names must be unique, got {[m.name for m in modes]}")
        extra = cfg.null_action + cfg.keep_best
        for m in modes:
            if m.samples < 1 + extra:
                raise ValueError(f"mode {m.name!r}: needs more than {extra} samples, got {m.samples}")
            bad = [ch for ch in m.fixed if not 0 <= ch < cfg.nu]
            if bad:
                raise ValueError(f"mode {m.name!r}: fixed channels {bad} outside 0..{cfg.nu - 1}")
            # η_i (paper Eq. 6) counts the samples that carry weight, so η_i ≤ K_i: a window above
            # it is never met, and adaptation would drive λ_i to its largest value every iteration.
            # η_l = K_i is allowed (approached as λ grows). The fused row has S ≥ K_i samples.
            if cfg.eta_bounds is not None and cfg.eta_bounds[0] > m.samples:
                raise ValueError(f"mode {m.name!r}: {m.samples} samples cannot reach the eta window "
                                 f"{tuple(cfg.eta_bounds)}: eta counts the samples that carry "
                                 f"weight, so eta_l must be <= {m.samples}")
        self._modes = modes
        self._s = sum(m.samples for m in modes)
        self._layout = _Layout.build([m.samples for m in modes], c.device)

        # Pinning as v·keep + value (keep 0 on pinned channels), exact for finite v; and each
        # mode's null action: zero, inside the bounds, pinned.
        keep = torch.ones(self._s, 1, cfg.nu, dtype=c.dtype, device=c.device)
        value = torch.zeros_like(keep)
        for m, rows in zip(modes, self._layout.slices):
            for ch, val in m.fixed.items():
                keep[rows, :, ch] = 0.0
                value[rows, :, ch] = val
        last = self._layout.last
        self._null = c.box.project(c.zeros(len(modes))) * keep[last] + value[last]
        pinned = keep == 0
        self._pin_keep = keep if bool(pinned.any()) else None
        self._pin_value = value
        # a clamp to bounds whose pinned channels have lo = hi = the pinned value
        self._clamp = None
        if not c.box.squash and (c.box.active or self._pin_keep is not None):
            inf = torch.full_like(keep, math.inf)
            lo, hi = (c.box.lo, c.box.hi) if c.box.active else (-inf, inf)
            self._clamp = (torch.where(pinned, value, lo), torch.where(pinned, value, hi))
