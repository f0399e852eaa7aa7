"""Importance weights (thesis Alg. 2 lines 25-29; paper Eqs. 5-7, 9-11) and the temperature
adaptation of paper Alg. 3, in NumPy on the host.

Rows are independent weighting problems (one per mode, plus the fused one), so everything here
works on ``[..., K]`` costs and reduces over the last dimension. These are a few hundred to a
few thousand numbers per iteration, where a torch call costs two to three NumPy ones and far
more once a rollout has run on every core (its dispatcher's code is evicted): the planners hand
their total costs ``[S]`` over once and take the weights back (on a GPU a few small transfers
an iteration, where the torch version synchronised on every adaptation step anyway).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

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


def finite_costs(costs: np.ndarray) -> np.ndarray:
    """Maps NaN and ±inf total costs ``[S]`` to ``+inf``: the rollout diverged (or the objective
    failed), so it gets zero weight, like padding, and does not count as a sample in the
    temperature adaptation. Not a large finite stand-in: its gap would enter the bracket of
    λ (paper Alg. 3) and, near the float maximum, overflow it to λ = inf; nor ``-inf`` kept as
    it is: a diverged rollout is no perfect one. Finite costs pass unchanged."""
    return np.where(np.isfinite(costs), costs, np.inf)


def softmin_weights(costs: np.ndarray, lam) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exponentiated-cost weights with the min-cost shift.

    ω_k = exp(-(S_k - β)/λ) / η,  η = Σ_k exp(-(S_k - β)/λ),  β = min_k S_k
    (paper Eqs. 5-7 / 9-11).

    Args:
        costs: ``[..., K]`` total costs S_k; ``+inf`` entries get zero weight (padding, diverged
            rollouts). No NaN or ``-inf``: :func:`finite_costs` maps them to ``+inf`` first.
        lam: temperature λ > 0, finite, a float or ``[..., 1]`` array.

    Returns:
        weights ``[..., K]`` (sum 1 per row), η ``[...]``, β ``[...]``. A row without a finite
        cost has all weights 0, η = 0 and β = ``+inf``: there is nothing to average.
    """
    beta = costs.min(axis=-1, keepdims=True)
    w, eta = gap_weights(cost_gaps(costs, beta), lam)
    return w, eta, beta[..., 0]


def cost_gaps(costs: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Gaps d = S - β ``[..., K]`` to the row minima ``beta [..., 1]``; a row of +inf only
    would give inf - inf = NaN, so it is shifted by 0 instead and keeps gaps of +inf."""
    return costs - np.where(np.isfinite(beta), beta, 0.0)


def gap_weights(gaps: np.ndarray, lam) -> tuple[np.ndarray, np.ndarray]:
    """:func:`softmin_weights` from the gaps ``[..., K]`` of :func:`cost_gaps`: weights
    ``[..., K]`` and η ``[...]``, for a caller that has the gaps already (M3P2I adapts λ on
    them)."""
    e = np.exp(-gaps / lam)
    eta = e.sum(axis=-1, keepdims=True)
    # η ≥ 1 in any row with a finite cost (its minimum gives e^0 = 1 exactly), so the floor
    # changes nothing there and turns 0/0 into 0 in a row without one.
    return e / np.maximum(eta, 1.0), eta[..., 0]


@dataclass(frozen=True)
class Weights:
    """One update's weighting of ``S`` samples in N modes plus the fused problem (paper
    Eqs. 5-7 per mode, 9-11 fused); host arrays, row i < N the mode i, row N the fused one.

    Attributes:
        w: ``[N + 1, S]`` weights; a mode's row is 0 outside its own samples, so one matrix
            product with the samples gives every mean (paper Eqs. 8, 12).
        eta: ``[N + 1]`` normalisers η (0: no finite cost in the row).
        beta: ``[N + 1]`` lowest costs β (``+inf``: none finite).
        lam: ``[N + 1]`` temperatures used (adapted, paper Alg. 3, when asked).
        best: ``[N]`` sample row of each mode's lowest cost (its first row when none is finite).
        costs: ``[S]`` the total costs weighed, diverged rollouts ``+inf``.
    """

    w: np.ndarray
    eta: np.ndarray
    beta: np.ndarray
    lam: np.ndarray
    best: np.ndarray
    costs: np.ndarray


def weigh(
    costs: np.ndarray,
    modes: Sequence[slice],
    lam: np.ndarray,
    eta_bounds: tuple[float, float] | None,
    max_iters: int,
) -> Weights:
    """Weights of total costs ``[S]`` for each mode (its rows ``modes[i]``) and for all of them
    together, with the temperatures ``lam [N + 1]`` adapted first when ``eta_bounds`` is given.

    Diverged rollouts (NaN, ±inf) are +inf, like the other modes' samples in a mode's row; a
    row with no finite cost at all gets zero weights and keeps its λ."""
    n = len(modes)
    if n == 1 and lam[0] == lam[1]:
        steady = _weigh_steady(costs, lam, eta_bounds)
        if steady is not None:
            return steady
    costs = finite_costs(costs)
    # one mode: its row and the fused one are the same weighting while their λ agree, so it
    # is made once and repeated
    single = n == 1 and lam[0] == lam[1]
    if single:
        table, lam = costs[None], lam[:1]  # [1, S]
    else:
        table = np.full((n + 1, costs.shape[0]), np.inf)  # [N + 1, S]
        for i, rows in enumerate(modes):
            table[i, rows] = costs[rows]
        table[n] = costs
    beta = table.min(axis=-1, keepdims=True)
    gaps = cost_gaps(table, beta)
    if eta_bounds is not None:
        lam = adapt_temperature(gaps, lam, eta_bounds, max_iters)
    w, eta = gap_weights(gaps, lam[:, None])
    beta = beta[:, 0]
    if single:
        w, eta, beta, lam = (np.repeat(x, 2, axis=0) for x in (w, eta, beta, lam))
    best = np.array([rows.start + int(np.argmin(costs[rows])) for rows in modes])
    return Weights(w=w, eta=eta, beta=beta, lam=lam, best=best, costs=costs)


def _weigh_steady(
    costs: np.ndarray, lam: np.ndarray, eta_bounds: tuple[float, float] | None
) -> Weights | None:
    """:func:`weigh` of one mode whose costs ``[S]`` have no NaN or -inf and whose λ (``lam [2]``,
    equal) keeps η in its window: a planner's usual iteration, in a third of the NumPy calls
    (each pays for its code again after a rollout) and to the same bits. ``None`` in any
    other case, for :func:`weigh` to handle."""
    k = int(costs.argmin())  # a NaN's row if there is one
    beta = costs[k]
    # β is NaN with a NaN cost, -inf with a -inf one, +inf with no finite one: the general
    # path's cases; a +inf cost among finite ones has weight exp(-inf) = 0 here as there
    if not math.isfinite(beta):
        return None
    e = np.subtract(costs, beta)  # the gaps d (cost_gaps)
    np.exp(np.divide(e, -lam[0], out=e), out=e)  # exp(-d/λ), as gap_weights computes it
    eta = e.sum()
    if eta_bounds is not None and not eta_bounds[0] <= eta <= eta_bounds[1]:
        return None
    w = np.empty((2, costs.shape[0]), dtype=costs.dtype)
    np.divide(e, eta, out=w[0])
    w[1] = w[0]
    return Weights(
        w=w,
        eta=np.array([eta, eta]),
        beta=np.array([beta, beta]),
        lam=lam.copy(),
        best=np.array([k]),
        costs=costs,
    )


def adapt_temperature(
    gaps: np.ndarray, lam: np.ndarray, eta_bounds: tuple[float, float], max_iters: int
) -> np.ndarray:
    """Re-tune λ per row until η(λ) = Σ_k exp(-d_k/λ) lies in ``[η_l, η_u]`` (paper Alg. 3).

    paper Alg. 3 multiplies λ by 0.9 or 1.2 until η is in the window, which needs tens to hundreds
    of steps when the cost scale changes by orders of magnitude and never ends when the window is
    unreachable. Here a row whose current λ already gives η in the window keeps it (temporal
    consistency); otherwise a safeguarded Newton iteration on log η(log λ) aims at the window's
    geometric centre inside a bracket derived from the gaps (Newton steps that leave the bracket
    become bisection steps). The start is clamped into the bracket, so the step count does not
    depend on how far the old λ was off: 1-5 steps for cost spreads from 1e-3 to 1e6 and windows
    (1.5, 2) to (10, 30), where the 0.9/1.2 rule needs ~80 from λ = 1 to λ = 1e6. ``max_iters`` caps
    it.
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
        window). Some forty NumPy steps on a few hundred numbers per row: on [3, 400] gaps,
        when it iterates, 110 µs, where the same steps in torch took 260 µs.
    """
    eta_l, eta_u = eta_bounds
    # inf/inf, 0·inf and log(0) are expected here (padding, rows without spread) and handled
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.exp(-gaps / lam[:, None]).sum(axis=-1)
        done = (eta >= eta_l) & (eta <= eta_u)
        if done.all():
            return lam

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
