"""What one planner iteration returns: the plan, each mode's best sequence, the weights, and
per-mode diagnostics made only when read."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from .temperature import Weights


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
        return self.diag[: self.num_modes]

    @property
    def mode_costs(self) -> Tensor:
        """``[N]`` lowest total cost among each mode's samples (β_i, paper Eq. 7)."""
        n = self.num_modes
        return self.diag[n : 2 * n]

    @property
    def etas(self) -> Tensor:
        """``[N]`` per-mode normalisers η_i (paper Eq. 6), roughly the number of samples that
        count."""
        n = self.num_modes
        return self.diag[2 * n : 3 * n]

    @property
    def fused_eta(self) -> Tensor:
        """``[]`` normaliser η of the fused weights (paper Eq. 10)."""
        return self.diag[3 * self.num_modes]

    @property
    def lambdas(self) -> Tensor:
        """``[N]`` per-mode temperatures λ_i used this iteration."""
        n = self.num_modes
        return self.diag[3 * n + 1 : 4 * n + 1]

    @property
    def fused_lambda(self) -> Tensor:
        """``[]`` temperature λ of the fused weights."""
        return self.diag[4 * self.num_modes + 1]


def diagnostics(wt: Weights, starts: list[int]) -> np.ndarray:
    """:attr:`PlanResult.diag` of an update's weighting ``wt`` of N modes whose rows start at
    ``starts [N]``: each mode's share of the fused weights, β_i, η and λ (the modes', then
    the fused one's)."""
    n = len(starts)
    return np.concatenate([np.add.reduceat(wt.w[n], starts), wt.beta[:n], wt.eta, wt.lam])
