"""Parameters of MPPI / M3P2I and of one planning mode.

Both dataclasses are frozen and validate themselves on construction, so a planner never runs
with a half-sensible configuration; the scenario loader builds them from YAML and turns the
``ValueError`` into a message naming the file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal


@dataclass(frozen=True)
class MPPIConfig:
    """Sampling, weighting and update parameters shared by all modes.

    Attributes:
        horizon: T, control steps per sampled sequence.
        nu: number of control channels.
        noise_sigma: per-channel standard deviation of the sampling noise, length ``nu``
            (Σ = diag(noise_sigma²)).
        sampling: ``"halton"`` (Halton-spline noise, paper Sec. II.C) or ``"gaussian"``
            (i.i.d. per step, thesis Alg. 2 line 13).
        halton_rotate: re-randomise the Halton set every iteration by a random
            Cranley-Patterson shift; ``False`` reuses one fixed set, as the paper does
            (see ``sampling.py`` for the trade-off).
        knot_every: Halton-spline knot spacing in control steps.
        spline_degree: degree of the B-spline through the knots (lowered automatically when the
            horizon has too few knots for it).
        gamma: discount γ of the per-step costs (paper Eq. 4); 1 = undiscounted.
        lambda_init: initial (and, without adaptation, fixed) temperature λ of every mode and
            of the fused weights.
        eta_bounds: ``(η_l, η_u)`` window for the normaliser η (paper Alg. 3): λ is re-tuned each
            iteration until η falls inside. ``None`` keeps λ fixed.
        adapt_iters: most root-finding steps of one temperature adaptation (paper Alg. 3 bound).
        alpha_u: step size α_u of the fused mean (paper Eq. 12); 1 = take the new estimate.
        u_min, u_max: per-channel control bounds (``±inf`` allowed with ``"clamp"``), or both
            ``None`` for unbounded controls.
        bound: ``"clamp"`` projects samples onto the box, ``"squash"`` maps them through a
            tanh into it (smooth near the bounds, needs finite bounds).
        savgol_window: Savitzky-Golay window over the horizon (odd, ≤ horizon); 0 = no smoothing.
            The thesis code uses 9.
        savgol_order: Savitzky-Golay polynomial order (< window).
        null_action: make the last sample of every mode the zero control (fixed channels
            pinned), a safe braking option always evaluated.
        keep_best: make the first sample of every mode that mode's best sequence of the previous
            iteration, shifted by one step (paper: best trajectories carried over).
        control_cost: scale of the importance-sampling control cost
            λ/2 Σ_t (u_tᵀΣ⁻¹u_t + 2u_tᵀΣ⁻¹ε_t) (thesis Alg. 2 line 18), with λ = ``lambda_init``
            even when temperatures adapt; 0 = off.
        seed: seed of the Halton set and of every random draw.
    """

    horizon: int
    nu: int
    noise_sigma: tuple[float, ...]
    sampling: Literal["halton", "gaussian"] = "halton"
    halton_rotate: bool = True
    knot_every: int = 4
    spline_degree: int = 2
    gamma: float = 1.0
    lambda_init: float = 1.0
    eta_bounds: tuple[float, float] | None = None
    adapt_iters: int = 20
    alpha_u: float = 1.0
    u_min: tuple[float, ...] | None = None
    u_max: tuple[float, ...] | None = None
    bound: Literal["clamp", "squash"] = "clamp"
    savgol_window: int = 0
    savgol_order: int = 2
    null_action: bool = True
    keep_best: bool = True
    control_cost: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        def need(ok: bool, what: str) -> None:
            if not ok:
                raise ValueError(f"MPPIConfig: {what}")

        need(self.horizon >= 1, f"horizon must be >= 1, got {self.horizon}")
        need(self.nu >= 1, f"nu must be >= 1, got {self.nu}")
        need(
            len(self.noise_sigma) == self.nu,
            f"noise_sigma needs {self.nu} entries, got {len(self.noise_sigma)}",
        )
        need(
            all(s > 0 and math.isfinite(s) for s in self.noise_sigma),
            f"noise_sigma entries must be finite and > 0, got {self.noise_sigma}",
        )
        need(
            self.sampling in ("halton", "gaussian"),
            f"sampling must be 'halton' or 'gaussian', got {self.sampling!r}",
        )
        need(self.knot_every >= 1, f"knot_every must be >= 1, got {self.knot_every}")
        need(self.spline_degree >= 1, f"spline_degree must be >= 1, got {self.spline_degree}")
        need(0.0 < self.gamma <= 1.0, f"gamma must be in (0, 1], got {self.gamma}")
        need(
            self.lambda_init > 0 and math.isfinite(self.lambda_init),
            f"lambda_init must be finite and > 0, got {self.lambda_init}",
        )
        if self.eta_bounds is not None:
            lo, hi = self.eta_bounds
            need(
                1.0 <= lo <= hi,
                f"eta_bounds must satisfy 1 <= eta_l <= eta_u, got {self.eta_bounds}",
            )
        need(self.adapt_iters >= 1, f"adapt_iters must be >= 1, got {self.adapt_iters}")
        need(0.0 < self.alpha_u <= 1.0, f"alpha_u must be in (0, 1], got {self.alpha_u}")
        need((self.u_min is None) == (self.u_max is None), "give both u_min and u_max, or neither")
        if self.u_min is not None:
            need(
                len(self.u_min) == self.nu and len(self.u_max) == self.nu,
                f"u_min and u_max need {self.nu} entries each",
            )
            need(
                all(lo < hi for lo, hi in zip(self.u_min, self.u_max)),
                f"u_min must be < u_max per channel, got {self.u_min}, {self.u_max}",
            )
        need(
            self.bound in ("clamp", "squash"),
            f"bound must be 'clamp' or 'squash', got {self.bound!r}",
        )
        if self.bound == "squash" and self.u_min is not None:
            need(
                all(map(math.isfinite, self.u_min + self.u_max)),
                "bound 'squash' needs finite u_min, u_max",
            )
        if self.savgol_window:
            need(
                self.savgol_window % 2 == 1
                and 0 <= self.savgol_order < self.savgol_window <= self.horizon,
                f"savgol_window must be odd, > savgol_order and <= horizon "
                f"(got window {self.savgol_window}, order {self.savgol_order}, "
                f"horizon {self.horizon})",
            )
        need(self.control_cost >= 0.0, f"control_cost must be >= 0, got {self.control_cost}")


@dataclass(frozen=True)
class ModeSpec:
    """One alternative plan of M3P2I: a name, its share of samples, and pinned channels.

    Attributes:
        name: identifies the mode across :meth:`M3P2I.set_modes` calls (its mean is kept).
        samples: K_i, rollouts owned by this mode.
        fixed: control channel index -> value the channel is pinned to in every sample of
            this mode (e.g. suction on = 1.0, gripper closed).
    """

    name: str
    samples: int
    fixed: dict[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.samples < 1:
            raise ValueError(f"ModeSpec {self.name!r}: samples must be >= 1, got {self.samples}")
