"""An objective's norm terms evaluated in one pass: distances, speeds and contact forces
(navigation's whole objective, thesis Eqs. 4.5 and 4.7; the distances and contact forces of
pick_place's).

Each such term is a sum of Euclidean norms of affine maps of a step's sensor values
(:class:`~planner_client.costs.base.Norm`). With G norms in all, built from m vector
components, the per-step cost of the objective is

    c[s, t] = Σ_g W[t, g] · sqrt(max(floor_g, Σ_{i ∈ g} z[s, t, i]²)),   z = x[s, t] L + b,

with ``x [S, T, nsensordata]`` the rollouts' sensors, ``L [nsensordata, m]`` and ``b [m]`` the
terms' maps, and ``W [T, G]`` each norm's term weight times its running/terminal mask (paper
Eq. 4). That is six tensor operations whatever the number of terms, where each term alone takes
four to seven: after a rollout has cooled the caches every operation costs some 15-40 µs on the
CPU, whatever its size, so the count is what matters (docs/speed.md).
"""

from __future__ import annotations

import torch

from planner_client.costs.base import CostTerm
from planner_client.sensors import SensorColumns


class NormObjective:
    """The weighted sum of ``terms``, each a term whose :meth:`CostTerm.norms` is not ``None``,
    with its ``[T]`` weights (weight · mask, summed over the entries listing it).

    Args:
        terms: ``(term, weights [T])`` pairs, one per distinct term.
        sensor_columns: where each sensor's values are in ``sensordata``.
        nsensordata: width of ``sensordata``.
    """

    def __init__(
        self,
        terms: list[tuple[CostTerm, torch.Tensor]],
        sensor_columns: SensorColumns,
        nsensordata: int,
    ):
        weights = terms[0][1]
        dtype, device = weights.dtype, weights.device
        components, group, floors, columns = [], [], [], []
        for term, w in terms:
            for norm in term.norms():
                for comp in norm.components:
                    components.append(comp)
                    group.append(len(floors))
                floors.append(norm.floor)
                columns.append(w)
        m, g = len(components), len(floors)
        lin = torch.zeros(nsensordata, m, dtype=dtype, device=device)  # L
        bias = torch.zeros(m, dtype=dtype, device=device)  # b
        for i, (b, parts) in enumerate(components):
            bias[i] = b
            for req, index, coef in parts:
                lin[sensor_columns.spans[req].start + index, i] += coef
        self.lin = lin
        self.bias = bias if bool(bias.any()) else None
        groups = torch.zeros(m, g, dtype=dtype, device=device)  # component -> norm
        groups[torch.arange(m, device=device), torch.tensor(group, device=device)] = 1.0
        self.groups = groups
        self.floor = torch.tensor(floors, dtype=dtype, device=device)  # [G]
        # W [T, G] as the block-diagonal [T·G, T] that sums each step's weighted norms
        weights = torch.stack(columns, dim=-1)
        self.weights = torch.block_diag(*weights[:, :, None])

    def __call__(self, sensordata: torch.Tensor) -> torch.Tensor:
        """Per-step costs ``[S, T]`` of ``sensordata [S, T, nsensordata]``."""
        s, t, n = sensordata.shape
        x = sensordata.reshape(s * t, n)
        z = x @ self.lin if self.bias is None else torch.addmm(self.bias, x, self.lin)
        norms = (z.mul_(z) @ self.groups).clamp_min_(self.floor).sqrt_()  # [S·T, G]
        return norms.view(s, -1) @ self.weights


def fusable(terms: list[CostTerm]) -> bool:
    """Whether every one of ``terms`` is a sum of norms, and there is at least one norm (a
    contact force against no obstacle is none)."""
    norms = [term.norms() for term in terms]
    return all(n is not None for n in norms) and any(norms)
