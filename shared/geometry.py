"""Rotation utilities shared by costs, observers and success tests.

Everything is batched over leading dimensions, so the planner can apply it to rollout sensor data
``[samples, horizon, ...]`` without Python loops. With a torch tensor among the arguments the
maths runs in torch: NumPy arguments beside it take its dtype and device, and the result is a
tensor. With NumPy arguments only it runs in NumPy and returns NumPy, so the world server (its
success tests and observers) never imports torch, which costs it a second and a half at start-up.
Rotation matrices have the frame's axes as columns, as MuJoCo's ``xmat`` reshaped to
``[3, 3]``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

ArrayLike = "torch.Tensor | np.ndarray"

# World axes a distance may be measured along: ``xy`` ignores height; ``xz`` and ``yz`` ignore
# one horizontal axis (e.g. a side grasp lining up level with a cube before it moves in along y).
# The one definition costs, predicates, metrics and the scenario loader use.
AXES: dict[str, tuple[int, ...]] = {
    "xy": (0, 1),
    "xz": (0, 2),
    "yz": (1, 2),
    "xyz": (0, 1, 2),
    "x": (0,),
    "y": (1,),
    "z": (2,),
}
# the same as basic slices: views, where a list index would copy (38 µs per call on a
# [400, 15, 3] tensor, twice per objective term and iteration)
_SLICES = {
    "xy": slice(0, 2),
    "xz": slice(0, 3, 2),
    "yz": slice(1, 3),
    "xyz": slice(0, 3),
    "x": slice(0, 1),
    "y": slice(1, 2),
    "z": slice(2, 3),
}


def select_axes(x: ArrayLike, axes: str) -> ArrayLike:
    """The components of ``x [..., 3]`` along ``axes`` (a key of :data:`AXES`) ->
    ``[..., 1, 2 or 3]``; NumPy stays NumPy, a tensor stays a tensor."""
    if axes not in AXES:
        raise ValueError(f"unknown axes {axes!r}; one of: {', '.join(AXES)}")
    return x if axes == "xyz" else x[..., _SLICES[axes]]


def _is_torch(*xs: ArrayLike) -> bool:
    """Whether any argument is a torch tensor (torch is then already imported by the caller)."""
    return any(type(x).__module__.startswith("torch") for x in xs)


def _tensors(*xs: ArrayLike) -> list[torch.Tensor]:
    """Inputs as tensors of one floating dtype on one device. NumPy inputs join the tensor
    inputs (dtype and device of the tensors, e.g. a float64 goal against float32 rollouts);
    with NumPy inputs only, their promoted dtype on the CPU."""
    import torch

    given = [x for x in xs if isinstance(x, torch.Tensor)]
    ts = [torch.as_tensor(x) for x in xs]
    dtype = (given or ts)[0].dtype
    for t in (given or ts)[1:]:
        dtype = torch.promote_types(dtype, t.dtype)
    if not dtype.is_floating_point:
        dtype = torch.get_default_dtype()
    device = given[0].device if given else ts[0].device
    return [t.to(device=device, dtype=dtype) for t in ts]


def symmetric_orientation_error(rot_u: ArrayLike, rot_v: ArrayLike) -> torch.Tensor:
    """Orientation distance between two frames of a fully symmetric object (paper Eq. 33).

    ``phi(S_u, S_v) = min_{i,j in 1..3} 2 - |u1 . v_i| - |u2 . v_j|``, where ``u1, u2`` are the
    first two axes of frame u and ``v_i`` any axis of frame v. The two minimisations are
    independent, as in paper Eq. 33, so ``phi = 2 - max_i |u1 . v_i| - max_j |u2 . v_j|``. It is 0
    exactly when the frames are in "general equivalence" (Definition 1: every axis of one is
    collinear with an axis of the other): for orthonormal u1, u2 both maxima can reach 1 only on
    different axes of v (Proposition 1 / Theorem 1). Any of the 24 rotations of a cube onto
    itself, including flips, therefore costs nothing. Always 0 <= phi <= 2 - 2/sqrt(3).

    Away from zero phi is not symmetric in its arguments, because only u's first two axes are
    matched (random pairs differ by up to about 0.3 when swapped); it is when the relative
    rotation is about u's third axis, e.g. a cube and its goal both lying on a table. Pass the
    frames in the same order everywhere (costs, observers, success tests) so they agree.

    The planner's cost computes the same phi from v's axes in u's frame, as MuJoCo's frame axis
    sensors give them: :func:`planner_client.costs.poses.symmetric_orientation_error_relative`.

    Args:
        rot_u, rot_v: rotation matrices ``[..., 3, 3]`` (axes as columns); leading dimensions
            broadcast, e.g. rollout orientations ``[S, T, 3, 3]`` against one goal ``[3, 3]``.

    Returns:
        ``[...]`` phi values (broadcast leading shape): a tensor if either argument is one,
        else a NumPy array.
    """
    if not _is_torch(rot_u, rot_v):
        u, v = np.asarray(rot_u, dtype=float), np.asarray(rot_v, dtype=float)
        cos = np.abs(np.swapaxes(u[..., :, :2], -1, -2) @ v)
        return np.maximum(2.0 - cos.max(axis=-1).sum(axis=-1), 0.0)
    import torch

    u, v = _tensors(rot_u, rot_v)
    # cos[..., a, i] = u_a . v_i for a in (1, 2)
    cos = torch.matmul(u[..., :, :2].transpose(-1, -2), v).abs()
    return (2.0 - cos.amax(dim=-1).sum(dim=-1)).clamp_min(0.0)
