"""Objectives: the plan interface's cost for one action, a weighted sum of named terms."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from planner_client.costs.base import TERMS, CostTerm, RolloutBatch, TermContext
from planner_client.costs.norms import NormObjective, fusable
from planner_client.plugins import exception_summary, origin
from planner_client.sensors import SensorRequest
from shared.config import ConfigError, ErrorLog, Section, one_of
from shared.scenario import ObjectiveConfig, TermConfig

_WHEN = ("all", "running", "terminal")


@dataclass
class WeightedTerm:
    term: CostTerm
    weight: float
    when: str  # all steps, running steps only (t < T-1), or the terminal step only (paper Eq. 4)
    source: str = ""  # the YAML file and key path of the entry, for messages about the term
    path: str = ""


@dataclass
class Objective:
    """``S(V)`` per step: Σ_terms weight · term, masked to running/terminal steps.

    The last column of the result is the terminal cost φ of paper Eq. 4; the planner applies the
    discount γ^t. An objective with several terms that are norms (distances, speeds, contact
    forces) computes them in one pass (:class:`~planner_client.costs.norms.NormObjective`) and
    adds the others one by one.
    """

    name: str
    terms: list[WeightedTerm]
    fixed: dict[int, float]  # control channel -> pinned value for this mode
    _masks: dict = field(default_factory=dict, repr=False)
    _fused: dict = field(default_factory=dict, repr=False)

    def sensors(self) -> list[SensorRequest]:
        return [r for wt in self.terms for r in wt.term.sensors()]

    def __call__(
        self, batch: RolloutBatch, values: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """Per-step costs ``[S, T]`` of the batch's rows.

        ``values``: unweighted term values ``[S, T]`` on these rows by :attr:`CostTerm.key`,
        already computed (a term several modes share, evaluated once on all their rows); a term
        found there is not evaluated again, and each one evaluated is added to it. Term values
        are never modified. Without ``values`` the norm terms are computed fused, to rounding
        the same costs.
        """
        sd = batch.sensordata
        if values is None:
            fused, rest = self._split(batch)
            if fused is not None:
                out = fused(sd)
                for term, weights in rest:
                    out.addcmul_(term(batch), weights)
                return out
            values = {}
        out = None
        for term, weights in self._weighted(batch.controls.shape[1], sd.dtype, sd.device):
            value = values.get(term.key)
            if value is None:
                value = values[term.key] = term(batch)
            out = value * weights if out is None else out.addcmul_(value, weights)
        return out

    def _split(
        self, batch: RolloutBatch
    ) -> tuple[NormObjective | None, list[tuple[CostTerm, torch.Tensor]]]:
        """The fused form of this objective's norm terms for the batch's sensor columns, shapes
        and device, and its other weighted terms; made once per columns object. ``None`` and all
        the terms when fewer than two are norms (one alone is as fast on its own)."""
        sd = batch.sensordata
        key = (batch.controls.shape[1], sd.shape[-1], sd.dtype, sd.device)
        columns, split = self._fused.get(key, (None, None))
        if columns is not batch.columns:
            weighted = self._weighted(key[0], sd.dtype, sd.device)
            norms, rest = [], []
            for term, w in weighted:
                (norms if fusable([term]) else rest).append((term, w))
            split = (
                (NormObjective(norms, batch.columns, sd.shape[-1]), rest)
                if len(norms) > 1
                else (None, weighted)
            )
            self._fused[key] = (batch.columns, split)
        return split

    def _weighted(
        self, horizon: int, dtype: torch.dtype, device: torch.device
    ) -> list[tuple[CostTerm, torch.Tensor]]:
        """Each distinct term (by :attr:`CostTerm.key`) with its weight · mask over the horizon
        ``[T]``, summed over the entries that list it (a distance in every step and again,
        weighted more, at the terminal one: paper Eq. 4): made once, then one multiply-add per
        distinct term per iteration."""
        key = (horizon, dtype, device)
        if key not in self._masks:
            merged: dict[str, tuple[CostTerm, torch.Tensor]] = {}
            for wt in self.terms:
                mask = torch.full((horizon,), wt.weight, dtype=dtype, device=device)
                if wt.when == "running":
                    mask[-1] = 0.0
                elif wt.when == "terminal":
                    mask[:-1] = 0.0
                if wt.term.key in merged:
                    merged[wt.term.key][1].add_(mask)
                else:
                    merged[wt.term.key] = (wt.term, mask)
            self._masks[key] = list(merged.values())
        return self._masks[key]


def build_objective(name: str, cfg: ObjectiveConfig, ctx: TermContext) -> Objective:
    """Validate an objective's terms against the registry and the model; build it. Every
    faulty term is reported, not only the first."""
    errors = ErrorLog()
    terms = [t for t in (errors.call(_weighted_term, tc, ctx) for tc in cfg.terms) if t]
    s = Section(dict(cfg.fixed), ctx.source, f"objectives.{name}.fixed")
    fixed = {}
    for act, value in cfg.fixed.items():
        channel = errors.call(ctx.channel, act, s, act)
        if channel is not None:
            fixed[channel] = value
    errors.raise_if_any()
    return Objective(name=name, terms=terms, fixed=fixed)


def _weighted_term(tc: TermConfig, ctx: TermContext) -> WeightedTerm:
    s = Section(
        {"term": tc.term, "weight": tc.weight, **tc.params}, tc.source or ctx.source, tc.path
    )
    s.req("term", str)
    s.opt("weight", 1.0)
    if tc.term not in TERMS:
        raise s.error(
            "term",
            "unknown cost term",
            tc.term,
            f"one of: {', '.join(sorted(TERMS))}; or a term of your own, from a module named by "
            "the scenario's plugins: or the planner's --plugins",
        )
    when = s.opt("when", "all", one_of(_WHEN))
    term = TERMS[tc.term].from_params(s, ctx)
    s.done()
    return WeightedTerm(term, tc.weight, when, s.source, s.path)


def check_term_values(objectives: dict[str, Objective], batch: RolloutBatch) -> None:
    """Evaluate each distinct term of ``objectives`` once on ``batch`` and raise, every term's
    fault at once, a :class:`ConfigError` at the term's YAML entry naming the term, its class
    and module (a plugin's file) and its objective, for a term that raised or whose value is
    not a ``torch.Tensor [S, T]`` of the dtype of ``batch.sensordata``, on its device: what
    would otherwise stop the planner mid-episode with a bare torch error naming none of them.

    NaN and inf pass: they are what a diverged rollout costs, and the planner already deals
    with them at run time: such a sample gets zero weight, and with no finite sample the robot
    gets its safe control and the fault names the objective
    (:meth:`~planner_client.motion.MotionPlanner.iterate`)."""
    errors = ErrorLog()
    seen = set()
    for name, objective in objectives.items():
        for wt in objective.terms:
            if wt.term.key not in seen:
                seen.add(wt.term.key)
                errors.call(_check_value, wt, name, batch)
    errors.raise_if_any()


def _check_value(wt: WeightedTerm, objective: str, batch: RolloutBatch) -> None:
    """:func:`check_term_values` of one term."""
    sd = batch.sensordata
    samples, steps = batch.controls.shape[:2]
    dtype = str(sd.dtype).removeprefix("torch.")
    expected = (
        f"a torch.Tensor [S, T] = [{samples}, {steps}] of {dtype} on {sd.device}: "
        "one cost per sample and step"
    )
    what = f"cost term {wt.term.name!r} of objective {objective!r} ({origin(type(wt.term))})"
    try:
        value = wt.term(batch)
    except Exception as exc:  # the term's own code failed: say where
        raise ConfigError(
            wt.source, wt.path, f"{what} raised {exception_summary(exc)}", expected=expected
        ) from None
    if not isinstance(value, torch.Tensor):
        kind = type(value)
        name = f"{kind.__module__}.{kind.__qualname__}".removeprefix("builtins.")
        fault = f"returned a {name}, not a torch.Tensor"
    elif tuple(value.shape) != (samples, steps):
        fault = f"returned a tensor of shape {list(value.shape)}"
    elif value.dtype != sd.dtype:
        fault = f"returned a tensor of dtype {str(value.dtype).removeprefix('torch.')}"
    elif value.device != sd.device:
        fault = f"returned a tensor on {value.device}"
    else:
        return
    raise ConfigError(wt.source, wt.path, f"{what} {fault}", expected=expected)
