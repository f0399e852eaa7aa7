"""Importance weights (thesis Alg. 2 lines 25-29; paper Eqs. 5-7, 9-11) and the temperature
adaptation of paper Alg. 3.

Rows are independent weighting problems (one per mode, plus the fused one), so everything here
works on ``[..., K]`` costs and reduces over the last dimension.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

# Bracket of log λ around the cost gaps d: at λ = d_min⁺/55 every non-minimal sample has weight
# ≤ e^{-55} relative to the best (η = number of ties), at λ = 50·d_max every sample has ≥ e^{-0.02}
# (η ≈ number of samples), so any reachable η lies inside.
_LOG_LO_MARGIN = math.log(55.0)
_LOG_HI_MARGIN = math.log(50.0)


def _log_lambda_range(dtype: np.dtype) -> tuple[float, float]:
    """Bounds on log λ that keep λ a normal float of ``dtype``, one e away from the smallest
    and the largest (exp of the bound itself may round past them)."""
    info = np.finfo(dtype)
    return math.log(info.tiny) + 1.0, math.log(info.max) - 1.0


def softmin_weights(costs: Tensor, lam: Tensor | float) -> tuple[Tensor, Tensor, Tensor]:
    """Exponentiated-cost weights with the min-cost shift.

    ω_k = exp(-(S_k - β)/λ) / η,  η = Σ_k exp(-(S_k - β)/λ),  β = min_k S_k   (paper Eqs. 5-7 / 9-11).

    Args:
        costs: ``[..., K]`` total costs S_k; ``+inf`` entries get zero weight (padding, diverged
            rollouts). No NaN or ``-inf``: :func:`~planner_client.mppi.m3p2i.finite_costs` maps
            them to ``+inf`` first.
        lam: temperature λ > 0, finite, a float or ``[..., 1]`` tensor.

    Returns:
        weights ``[..., K]`` (sum 1 per row), η ``[...]``, β ``[...]``. A row without a finite
        cost has all weights 0, η = 0 and β = ``+inf``: there is nothing to average.
    """
    beta = costs.amin(dim=-1, keepdim=True)
    w, eta = gap_weights(cost_gaps(costs, beta), lam)
    return w, eta, beta.squeeze(-1)


def cost_gaps(costs: Tensor, beta: Tensor) -> Tensor:
    """Gaps d = S - β ``[..., K]`` to the row minima ``beta [..., 1]``; a row of +inf only
    would give inf - inf = NaN, so it is shifted by 0 instead and keeps gaps of +inf."""
    return costs - beta.nan_to_num(posinf=0.0)


def gap_weights(gaps: Tensor, lam: Tensor | float) -> tuple[Tensor, Tensor]:
    """:func:`softmin_weights` from the gaps ``[..., K]`` of :func:`cost_gaps`: weights
    ``[..., K]`` and η ``[...]``, for a caller that has the gaps already (M3P2I adapts λ on
    them)."""
    e = torch.exp(-gaps / lam)
    eta = e.sum(dim=-1, keepdim=True)
    # η ≥ 1 in any row with a finite cost (its minimum gives e^0 = 1 exactly), so the clamp
    # changes nothing there and turns 0/0 into 0 in a row without one.
    return e / eta.clamp(min=1.0), eta.squeeze(-1)


def adapt_temperature(gaps: Tensor, lam: Tensor, eta_bounds: tuple[float, float],
                      max_iters: int) -> Tensor:
    """Re-tune λ per row until η(λ) = Σ_k exp(-d_k/λ) lies in ``[η_l, η_u]`` (paper Alg. 3).

    paper Alg. 3 multiplies λ by 0.9 or 1.2 until η is in the window, which needs tens to hundreds of steps
    when the cost scale changes by orders of magnitude and never ends when the window is unreachable.
    Here a row whose current λ already gives η in the window keeps it (temporal consistency);
    otherwise a safeguarded Newton iteration on log η(log λ) aims at the window's geometric centre
    inside a bracket derived from the gaps (Newton steps that leave the bracket become bisection
    steps). The start is clamped into the bracket, so the step count does not depend on how far
    the old λ was off: 1-5 steps for cost spreads from 1e-3 to 1e6 and windows (1.5, 2) to
    (10, 30), where the 0.9/1.2 rule needs ~80 from λ = 1 to λ = 1e6. ``max_iters`` caps it.
    A window outside the reachable range (η runs from the number of tied minima to the number of
    finite samples) gives the bracket end closest to it. λ stays a finite, normal float whatever
    the gaps: the bracket is capped where exp overflows or underflows (gaps near the float
    maximum would otherwise give λ = inf, and every weight NaN).

    Args:
        gaps: ``[G, K]`` cost gaps d = S - β ≥ 0 per row; ``+inf`` marks padding and diverged
            rollouts (not samples); a row of ``+inf`` only keeps its λ.
        lam: ``[G]`` current temperatures (warm start).
        eta_bounds: ``(η_l, η_u)``.
        max_iters: cap on root-finding steps, shared by all rows.

    Returns:
        ``[G]`` new temperatures, finite and > 0 (``lam`` itself when every row is in its
        window), on ``lam``'s device.

    The maths runs in NumPy on the host: some forty steps on a few hundred numbers per row,
    where a torch call costs two to three NumPy ones (on [3, 400] gaps, when it iterates: 110
    against 260 µs); on a GPU the gaps cross once per iteration, where the torch version
    synchronised on every step's ``done.all()`` anyway.
    """
    new = _adapt(gaps.detach().cpu().numpy(), lam.detach().cpu().numpy(), eta_bounds, max_iters)
    return lam if new is None else torch.as_tensor(new, dtype=lam.dtype, device=lam.device)


def _adapt(gaps: np.ndarray, lam: np.ndarray, eta_bounds: tuple[float, float],
           max_iters: int) -> np.ndarray | None:
    """:func:`adapt_temperature` on host arrays; ``None`` when every row is in its window."""
    eta_l, eta_u = eta_bounds
    # inf/inf, 0·inf and log(0) are expected here (padding, rows without spread) and handled
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.exp(-gaps / lam[:, None]).sum(axis=-1)
        done = (eta >= eta_l) & (eta <= eta_u)
        if done.all():
            return None

        target = 0.5 * (math.log(eta_l) + math.log(eta_u))
        finite = np.isfinite(gaps)
        d_min = np.where(finite & (gaps > 0), gaps, np.inf).min(axis=-1)
        d_max = np.where(finite, gaps, -np.inf).max(axis=-1)
        n_ties = (gaps == 0).sum(axis=-1)
        n_finite = finite.sum(axis=-1)
        log_min, log_max = _log_lambda_range(gaps.dtype)
        lo = np.clip(np.log(d_min) - _LOG_LO_MARGIN, log_min, log_max)
        hi = np.clip(np.log(d_max) + _LOG_HI_MARGIN, log_min, log_max)
        x = np.log(lam)

        # Rows with no spread cannot be tuned; rows whose window is out of reach go to the
        # nearest end.
        flat = np.isinf(d_min)
        too_many_ties = ~flat & (n_ties > eta_u)
        too_few_samples = ~flat & ~too_many_ties & (n_finite < eta_l)
        x = np.where(too_many_ties, lo, np.where(too_few_samples, hi, x))
        unreachable = flat | too_many_ties | too_few_samples
        done = done | unreachable
        x = np.where(done, x, np.clip(x, lo, hi))

        for _ in range(max_iters):
            scaled = gaps / np.exp(x)[:, None]
            e = np.exp(-scaled)
            eta = e.sum(axis=-1)
            done = unreachable | ((eta >= eta_l) & (eta <= eta_u))
            if done.all():
                break
            f = np.log(eta) - target
            lo = np.where(f < 0, x, lo)
            hi = np.where(f > 0, x, hi)
            # d log η / d log λ = Σ (d/λ) e^{-d/λ} / η; padding gives inf·0, which contributes
            # nothing.
            slope = np.nan_to_num(scaled * e, nan=0.0).sum(axis=-1) / eta
            newton = x - f / slope
            inside = np.isfinite(newton) & (newton > lo) & (newton < hi)
            x = np.where(done, x, np.where(inside, newton, 0.5 * (lo + hi)))
        return np.exp(x)
