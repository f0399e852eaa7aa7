"""``planner.model.variants``: copies of the planner's model with other masses, frictions and
gains, and their identification online (``identify``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from shared.config import (
    Section,
    deprecated,
    non_negative,
    one_of,
    positive,
    positive_int,
)
from shared.scenario.common import count_of, unit_weight

VARIANT_PARAMS = ("mass", "friction", "gain")


VARIANT_AGGREGATES = ("mean", "cvar", "worst")


VARIANT_SPREADS = ("split", "all", "identified")


@dataclass(frozen=True)
class IdentifyConfig:
    """``planner.model.variants.identify``: the variants reweighted by how well each predicted
    the last observed transition (planner_client.variants; docs/scenarios.md, "Model variants").
    ``position_sigma`` and ``velocity_sigma``: the spread of a prediction's error that a right
    model still makes (measurement noise, the mirror's estimates), for the free objects'
    positions and the robot's velocities; ``forget``: the share of the past evidence each new
    transition keeps (old evidence fades, so the ensemble widens again when the world changes);
    ``floor``: the share of the variants redrawn from the prior at each resampling;
    ``jitter``: each kept variant's factors moved by this fraction of the prior's half-width;
    ``window``: the world steps each prediction spans (1: from the previous state received;
    more: from the state ``window`` steps back, its objects' positions and velocities a line
    fitted through the poses received around it)."""

    position_sigma: float = 0.005
    velocity_sigma: float = 0.02
    forget: float = 0.9
    floor: float = 0.1
    jitter: float = 0.1
    window: int = 1

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class VariantsConfig:
    """``planner.model.variants``: ``count`` copies of the planner's model whose parameters are
    scaled by factors drawn (from ``seed``) uniformly in ``[1 - f, 1 + f]``, per scenario object
    for ``mass`` (masses and inertias) and ``friction`` (its contacts' friction), per actuator
    for ``gain`` (gain and bias). ``spread: split``: sample ``k`` rolls out in variant
    ``k mod count`` (no extra rollouts); ``all``: every sample in every variant, its cost the
    ``aggregate`` over them (``mean``, ``cvar``: the mean of the worst ``cvar_alpha`` share,
    ``worst``); ``identified``: every sample in one model at the identified factors (the
    variants only identify; needs ``identify``). ``identify``: the variants reweighted and
    resampled online."""

    count: int = 8
    seed: int = 0
    mass: float = 0.0
    friction: float = 0.0
    gain: float = 0.0
    spread: str = "split"
    aggregate: str = "mean"
    cvar_alpha: float = 0.25
    identify: IdentifyConfig | None = None

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k not in VARIANT_PARAMS + ("identify",)}
        out["params"] = {k: getattr(self, k) for k in VARIANT_PARAMS if getattr(self, k)}
        if self.identify is not None:
            out["identify"] = self.identify.as_dict()
        return out


def _fraction(value: Any) -> float:
    v = non_negative(value)
    if v >= 1:
        raise ValueError("must be < 1")
    return v


_FRACTION = "a fraction in [0, 1) (0.3: factors within ±30 %)"


# the most copies of the planner's model: each is a whole MjModel the planner holds (and, with
# spread: all, rolls every sample out in); count: 1000000 ran the planner out of memory
MAX_VARIANTS = 256
# spread: all rolls out count x planner.samples per mode and iteration
MAX_VARIANT_ROLLOUTS = 50_000

# the longest prediction the identifier scores, in world steps: the controller keeps the plans
# sent over that span (planner_client.controller)
MAX_IDENTIFY_WINDOW = 20


def _count(value: Any) -> int:
    v = positive_int(value)
    if v > MAX_VARIANTS:
        raise ValueError(f"more than {MAX_VARIANTS} copies of the planner's model")
    return v


def _window(value: Any) -> int:
    v = positive_int(value)
    if v > MAX_IDENTIFY_WINDOW:
        raise ValueError(f"must be <= {MAX_IDENTIFY_WINDOW}")
    return v


def read_variants(s: Section) -> VariantsConfig:
    p = s.section("params")
    params = {k: p.opt(k, 0.0, _fraction, _FRACTION) for k in VARIANT_PARAMS}
    p.done()
    if not any(params.values()):
        raise s.error(
            "params",
            "no parameter varies",
            dict(p.data),
            "at least one of " + ", ".join(f"{k}: f" for k in VARIANT_PARAMS) + f" ({_FRACTION})",
        )
    cfg = VariantsConfig(
        count=s.opt("count", 8, _count, f"an integer in [1, {MAX_VARIANTS}] (models)"),
        seed=s.opt("seed", 0, count_of, "an integer >= 0"),
        spread=_spread(s),
        aggregate=s.opt("aggregate", "mean", one_of(VARIANT_AGGREGATES)),
        cvar_alpha=s.opt("cvar_alpha", 0.25, unit_weight, "a share in (0, 1]"),
        identify=_identify(s.section("identify")) if s.has("identify") else None,
        **params,
    )
    if cfg.spread != "all" and s.has("aggregate"):
        raise s.error(
            "aggregate",
            "an aggregate needs every sample rolled out in every variant",
            cfg.aggregate,
            f"spread: all (with spread: {cfg.spread} each sample meets one model)",
        )
    if cfg.spread == "identified" and cfg.identify is None:
        raise s.error(
            "spread",
            "rollouts at the identified factors need the variants identified",
            cfg.spread,
            "an identify section (e.g. identify: {}), or spread: split or all",
        )
    s.done()
    return cfg


def _identify(s: Section) -> IdentifyConfig:
    cfg = IdentifyConfig(
        position_sigma=s.opt("position_sigma", 0.005, positive, "metres > 0"),
        velocity_sigma=s.opt("velocity_sigma", 0.02, positive, "m/s (rad/s) > 0"),
        forget=s.opt("forget", 0.9, unit_weight, "a share in (0, 1]"),
        floor=s.opt("floor", 0.1, _fraction, "a share in [0, 1)"),
        jitter=s.opt("jitter", 0.1, non_negative, "a fraction >= 0 of the prior's half-width"),
        window=s.opt("window", 1, _window, f"steps, an integer in [1, {MAX_IDENTIFY_WINDOW}]"),
    )
    s.done()
    return cfg


def _spread(s: Section) -> str:
    """``spread``, its old value ``estimate`` read as ``identified`` (it warns once)."""
    if s.data.get("spread") == "estimate":
        deprecated(f"{s.key_path('spread')}: estimate (in {s.source})", "write spread: identified")
        s.data = {**s.data, "spread": "identified"}
    return s.opt("spread", "split", one_of(VARIANT_SPREADS))
