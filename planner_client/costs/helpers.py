"""Helpers the cost terms share, public here rather than private to one term module: parameter
readers (frames, axes, a cosine value) and the small tensor maths several terms use."""

from __future__ import annotations

import functools

import torch

from planner_client.costs.base import RolloutBatch, TermContext
from planner_client.sensors import SensorRequest
from shared.config import Section, number, one_of
from shared.geometry import AXES, select_axes


def axes_param(s: Section, default: str = "xyz") -> str:
    """The ``axes`` parameter of a term: the world axes it measures along (:data:`AXES`).

    Push and pull terms default to ``xy``: robot, object and goal centres sit at different
    heights, and the planar angle is the one that says whether the robot is behind the object.
    """
    return s.opt("axes", default, one_of(AXES))


# Floor of |a|·|b| in a cosine: a robot exactly on the object, an object exactly on the goal or a
# zero control has no direction, and must cost nothing rather than NaN.
TINY = 1e-12


def cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """cos of the angle between ``a`` and ``b`` ``[..., d]`` -> ``[...]``; 0 if either is 0.

    Near zero, |a·b| <= |a||b| keeps the ratio in [-1, 1], so the cost stays bounded and
    continuous there too.
    """
    den = norm(a) * norm(b)
    return last_sum(a * b) / den.clamp_min(TINY)


def last_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum over a short last axis, ``[..., d] -> [...]``, as one matrix-vector product.

    Torch's CPU reductions over a last axis of a few entries cost some 20 ns per output element
    (on ``[200, 5, 7, 3]`` forces a ``sum(-1)`` took 180 µs, the product with a ones vector
    25 µs): terms reduce over 2-7 entries on every sample and step, so they sum this way."""
    return x @ _ones(x.shape[-1], x.dtype, x.device)


def norm(x: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over a short last axis (a position, a force), ``[..., d] -> [...]``:
    :func:`last_sum` of the squares (``torch.linalg.vector_norm`` reduces the slow way)."""
    return last_sum(x * x).sqrt_()


# Floor of a squared norm before its square root in :func:`sparse_norm`: its root, 1e-150,
# vanishes against any cost it is added to (the sum rounds back to that cost, bit for bit).
SQUARE_FLOOR = 1e-300


def sparse_norm(x: torch.Tensor) -> torch.Tensor:
    """:func:`norm` of vectors that are mostly exactly zero (contact forces: navigation's
    rollouts touch nothing in 6950 of 7000 sensor readings), ``[..., d] -> [...]``; a zero
    vector gives 1e-150 instead of 0. torch's CPU square root takes some 5 ns on an exact zero
    against under 1 ns on any other number (44 against 5 µs on [200, 5, 7]); the floor keeps
    it off zero, and leaves every square above 1e-300 (a force above 1e-150 N) as it is."""
    return last_sum(x * x).clamp_min_(SQUARE_FLOOR).sqrt_()


@functools.cache
def constant(
    values: tuple[float, ...], dtype: torch.dtype, device: torch.device = torch.device("cpu")
) -> torch.Tensor:
    """A term's parameter ``values`` as a tensor on ``device``, made once (read-only: terms run
    every planner iteration, and a new tensor costs as much as the operation using it)."""
    return torch.tensor(values, dtype=dtype, device=device)


@functools.lru_cache(maxsize=32)
def _ones(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``[n]`` ones for :func:`last_sum`, made once (read-only: matmul never writes it)."""
    return torch.ones(n, dtype=dtype, device=device)


def cos_rog(batch: RolloutBatch, a: str, obj: str, goal: str, axes: str) -> torch.Tensor:
    """cos θ_ROG of paper Eq. 16: angle at the object O between robot R and goal G, ``[S, T]``."""
    x_r, x_o, x_g = (batch.get(SensorRequest("framepos", f)) for f in (a, obj, goal))
    return cosine(select_axes(x_r - x_o, axes), select_axes(x_g - x_o, axes))


def frame_params(s: Section, ctx: TermContext, *keys: str) -> dict[str, str]:
    """The frame-name parameters ``keys``, each checked to exist in the model."""
    return {k: ctx.frame(s, k) for k in keys}


def cosine_value(value) -> float:
    """Converter for a cosine parameter (θ of paper Eq. 27): a number in [-1, 1]."""
    v = number(value)
    if not -1.0 <= v <= 1.0:
        raise ValueError("must be in [-1, 1]")
    return v
