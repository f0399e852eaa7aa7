"""Sampling noise for MPPI: i.i.d. Gaussian or Halton splines.

All samplers return *unit* noise of shape ``[S, T, nu]`` (marginal std ≈ 1); the planner scales it
by the per-channel σ. The returned tensor is a buffer owned by the sampler and overwritten by a
later :meth:`draw` (the next one, or the next block's), so callers use it before drawing again.

Halton splines (paper Sec. II.C, after STORM): a scrambled Halton set gives, for every sample and
channel, a few knot values spread evenly over the unit cube (low discrepancy: no clusters, no
holes, unlike i.i.d. draws of the same count); the inverse normal CDF maps them to N(0, 1), and a
B-spline through knots every ``knot_every`` steps turns them into smooth sequences over the
horizon. The spline is linear in the knot values, so it is precomputed as a ``[T, n_knots]``
basis matrix and one draw is one matmul.

Re-randomisation (``MPPIConfig.halton_rotate``, default on): the paper draws the Halton set once
and reuses it. A fixed set offers the same K perturbation shapes every iteration, so directions it
happens to miss are never explored and the update keeps a fixed bias from the set's finite-sample
asymmetry. Each draw therefore applies a random Cranley-Patterson rotation (one uniform shift per
Halton dimension, modulo 1, before the inverse CDF): every rotated set is still low-discrepancy,
each knot is exactly U(0, 1) so each sample is exactly a spline of N(0, 1) knots, and it costs one
add, one ``ndtri`` and one matmul on ``S × nu × n_knots`` numbers. Measured on the double
integrator (``scripts/benchmark_mppi.py``, docs/mppi.md): the fixed set leaves a steady-state
position error about 5× larger; the rotation's commands vary more from step to step than the fixed
set's, but less than half as much as with Gaussian noise.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from .cache import cached_prefix
from .config import MPPIConfig

# Keeps ndtri finite if a rotated Halton point lands on 0 or 1 exactly.
_U_EPS = 1e-9

# Rotated Halton draws made at once (HaltonSplineNoise.block): up to this many numbers per
# block (2^17 float64: 1 MiB), and no more than this many draws.
BLOCK_NUMBERS = 1 << 17
MAX_BLOCK = 32


def spline_basis(horizon: int, knot_every: int, degree: int) -> np.ndarray:
    """Interpolating B-spline design matrix from knot values to the horizon.

    Knots sit at steps 0, k, 2k, ... up to the first one at or beyond ``horizon - 1``, so every
    step lies inside the knot span. The degree is lowered when there are too few knots for it.

    Returns:
        ``[T, n_knots]`` matrix B with ``noise[t] = Σ_j B[t, j] · knot[j]``; rows at knots are unit
        vectors, so the marginal std is exactly 1 there and dips to ≈ 0.8 between knots.
    """
    n_knots = math.ceil((horizon - 1) / knot_every) + 1
    if n_knots == 1:
        return np.ones((horizon, 1))
    k = min(degree, n_knots - 1)

    def compute() -> np.ndarray:
        from scipy.interpolate import make_interp_spline

        knot_t = np.arange(n_knots) * knot_every
        return make_interp_spline(knot_t, np.eye(n_knots), k=k, axis=0)(np.arange(horizon))

    def same_knots(longer: int) -> bool:
        return math.ceil((longer - 1) / knot_every) + 1 == n_knots

    template = f"spline-T{{}}-every{knot_every}-k{k}"
    return cached_prefix(template, horizon, n_knots, compute, same_knots)


def halton_uniforms(samples: int, dims: int, seed: int) -> np.ndarray:
    """``[samples, dims]`` scrambled Halton points in (0, 1); scrambling removes the strong
    correlations plain Halton has between high-prime dimensions (many channels × knots)."""

    def compute() -> np.ndarray:
        from scipy.stats import qmc

        return qmc.Halton(d=dims, scramble=True, seed=seed).random(samples)

    return cached_prefix(f"halton-{{}}x{dims}-seed{seed}", samples, dims, compute)


class GaussianNoise:
    """I.i.d. standard normal noise per step (thesis Alg. 2 line 13), redrawn every call."""

    def __init__(
        self,
        samples: int,
        horizon: int,
        nu: int,
        seed: int,
        dtype: torch.dtype,
        device: torch.device,
    ):
        self._seed = seed
        self._gen = torch.Generator(device=device)
        self._out = torch.empty(samples, horizon, nu, dtype=dtype, device=device)
        self.reset()

    def reset(self) -> None:
        """Restart the random stream from the seed."""
        self._gen.manual_seed(self._seed)

    def draw(self) -> Tensor:
        """Returns ``[S, T, nu]`` unit noise."""
        return torch.randn(self._out.shape, generator=self._gen, out=self._out)


class HaltonSplineNoise:
    """Halton-spline noise; with ``rotate`` re-randomised each call by a Cranley-Patterson shift,
    otherwise the same set every call (as in the paper).

    Rotated draws are made :attr:`block` at a time (as many as fit in :data:`BLOCK_NUMBERS`
    numbers, at most :data:`MAX_BLOCK`): on the CPU the same random stream and noise as one at a
    time, bit for bit (a GPU's generator splits its stream by call, so there only the same
    distribution), but the six tensor operations of a draw run once per block, not per iteration,
    where after each rollout they paid for their code again (navigation's draw took 130 µs
    of a 3 ms iteration). At GPU scale a draw fills the block by itself."""

    def __init__(
        self,
        samples: int,
        horizon: int,
        nu: int,
        knot_every: int,
        degree: int,
        seed: int,
        rotate: bool,
        dtype: torch.dtype,
        device: torch.device,
    ):
        basis = spline_basis(horizon, knot_every, degree)
        n_knots = basis.shape[1]
        self._seed = seed
        self._basis_t = torch.as_tensor(basis.T.copy(), dtype=dtype, device=device)  # [J, T]
        # Halton dimension c·J + j is the knot j of channel c: [S, nu, J].
        self._knots_u = torch.as_tensor(
            halton_uniforms(samples, n_knots * nu, seed), dtype=dtype, device=device
        ).view(samples, nu, n_knots)
        self._gen = torch.Generator(device=device)
        self.block = (
            max(1, min(MAX_BLOCK, BLOCK_NUMBERS // (samples * nu * horizon))) if rotate else 1
        )
        self._shift = torch.empty(self.block, 1, nu, n_knots, dtype=dtype, device=device)
        self._z = torch.empty(self.block, samples, nu, n_knots, dtype=dtype, device=device)
        self._out = torch.empty(self.block, samples, nu, horizon, dtype=dtype, device=device)
        self._draws = list(self._out.transpose(2, 3).unbind(0))  # [S, T, nu] views, made once
        self._fixed = None
        if not rotate:
            self._splines(self._z.copy_(self._knots_u))
            self._fixed = self._draws[0]
        self.reset()

    def reset(self) -> None:
        """Restart the rotation stream from the seed."""
        self._gen.manual_seed(self._seed)
        self._next = self.block

    def draw(self) -> Tensor:
        """Returns ``[S, T, nu]`` unit noise: (rotated) knots -> N(0, 1) -> spline over T."""
        if self._fixed is not None:
            return self._fixed
        if self._next == self.block:
            torch.rand(self._shift.shape, generator=self._gen, out=self._shift)
            self._splines(torch.add(self._knots_u, self._shift, out=self._z).frac_())
            self._next = 0
        self._next += 1
        return self._draws[self._next - 1]

    def _splines(self, u: Tensor) -> None:
        """Uniform knots ``[B, S, nu, J]`` (overwritten) -> spline noise in the block's buffer,
        read as the B ``[S, T, nu]`` views of :attr:`_draws`."""
        z = torch.special.ndtri(u.clamp_(_U_EPS, 1 - _U_EPS), out=u)
        torch.mm(
            z.view(-1, z.shape[-1]), self._basis_t, out=self._out.view(-1, self._out.shape[-1])
        )


def make_noise(
    cfg: MPPIConfig, samples: int, dtype: torch.dtype, device: torch.device
) -> GaussianNoise | HaltonSplineNoise:
    """The sampler named by ``cfg.sampling`` for ``samples`` rows."""
    if cfg.sampling == "halton":
        return HaltonSplineNoise(
            samples,
            cfg.horizon,
            cfg.nu,
            cfg.knot_every,
            cfg.spline_degree,
            cfg.seed,
            cfg.halton_rotate,
            dtype,
            device,
        )
    return GaussianNoise(samples, cfg.horizon, cfg.nu, cfg.seed, dtype, device)
