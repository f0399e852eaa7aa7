"""``planner.mppi``: M3P2I's sampling, weighting and update parameters (docs/mppi.md), read and
checked at load like every other section, so that the world, ``m3p2i check`` and the planner all
refuse a typo or a value out of range before anything starts. What the file leaves out the
planner fills in from its model: the horizon is ``planner.horizon``, the bounds are the
actuators' ranges and the noise a quarter of each (``planner_client/problem.py``). Values are
kept as the file gives them (a list becomes a tuple), so a scenario plans as it did before the
section was typed."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

from shared.config import ConfigError, Section, flag, one_of, positive_int


@dataclass(frozen=True)
class MppiSettings:
    """The keys of ``planner.mppi``, each None when the file does not give it; their meaning is
    ``planner_client.mppi.MPPIConfig``'s."""

    noise_sigma: tuple[float, ...] | None = None
    sampling: str | None = None
    halton_rotate: bool | None = None
    knot_every: int | None = None
    spline_degree: int | None = None
    gamma: float | None = None
    lambda_init: float | None = None
    eta_bounds: tuple[float, float] | None = None
    adapt_iters: int | None = None
    alpha_u: float | None = None
    u_min: tuple[float, ...] | None = None
    u_max: tuple[float, ...] | None = None
    bound: str | None = None
    savgol_window: int | None = None
    savgol_order: int | None = None
    null_action: bool | None = None
    keep_best: bool | None = None
    control_cost: float | None = None
    seed: int | None = None

    def given(self) -> dict[str, Any]:
        """The keys the file gives: name -> value."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        return {k: v for k, v in out.items() if v is not None}


def _checked(ok: Callable[[Any], bool], why: str) -> Callable[[Any], Any]:
    """A converter that keeps the file's value (a list as a tuple) when ``ok`` holds."""

    def check(value: Any) -> Any:
        if isinstance(value, bool) or not ok(value):
            raise ValueError(why)
        return tuple(value) if isinstance(value, list) else value

    return check


def _real(v: Any) -> bool:
    """A YAML number a float holds (an integer such as 10**400 does not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        float(v)
    except OverflowError:
        return False
    return True


def _reals(v: Any, finite: bool = True) -> bool:
    return (
        isinstance(v, list)
        and len(v) > 0
        and all(_real(x) and not math.isnan(x) and (math.isfinite(x) or not finite) for x in v)
    )


def read_mppi(s: Section, horizon: int, samples: int) -> MppiSettings:
    """``planner.mppi`` checked against the ranges M3P2I accepts (``horizon`` and ``samples``:
    the planner section's); lengths against the actuators are the planner's check."""
    unit = _checked(lambda v: _real(v) and 0.0 < v <= 1.0, "must be in (0, 1]")
    cfg = MppiSettings(
        noise_sigma=s.opt(
            "noise_sigma",
            None,
            _checked(lambda v: _reals(v) and min(v) > 0, "must be finite numbers > 0"),
            "a list of standard deviations > 0, one per actuator",
        ),
        sampling=s.opt("sampling", None, one_of(("halton", "gaussian"))),
        halton_rotate=s.opt("halton_rotate", None, flag),
        knot_every=s.opt("knot_every", None, positive_int, "control steps >= 1"),
        spline_degree=s.opt("spline_degree", None, positive_int, "an integer >= 1"),
        gamma=s.opt("gamma", None, unit, "a discount in (0, 1]"),
        lambda_init=s.opt(
            "lambda_init",
            None,
            _checked(lambda v: _real(v) and 0 < v < math.inf, "must be finite and > 0"),
            "a temperature > 0",
        ),
        eta_bounds=s.opt(
            "eta_bounds",
            None,
            _checked(
                lambda v: _reals(v) and len(v) == 2 and 1.0 <= v[0] <= v[1],
                "must be [eta_l, eta_u] with 1 <= eta_l <= eta_u",
            ),
            f"[eta_l, eta_u], 1 <= eta_l <= eta_u, eta_l <= planner.samples ({samples})",
        ),
        adapt_iters=s.opt("adapt_iters", None, positive_int, "an integer >= 1"),
        alpha_u=s.opt("alpha_u", None, unit, "a step size in (0, 1]"),
        u_min=s.opt("u_min", None, _checked(lambda v: _reals(v, finite=False), "must be numbers")),
        u_max=s.opt("u_max", None, _checked(lambda v: _reals(v, finite=False), "must be numbers")),
        bound=s.opt("bound", None, one_of(("clamp", "squash"))),
        savgol_window=s.opt(
            "savgol_window",
            None,
            _checked(
                lambda v: isinstance(v, int) and v >= 0 and (v == 0 or (v % 2 and v <= horizon)),
                "must be 0 or odd and <= planner.horizon",
            ),
            f"0 (no smoothing) or an odd window <= planner.horizon ({horizon})",
        ),
        savgol_order=s.opt(
            "savgol_order",
            None,
            _checked(lambda v: isinstance(v, int) and v >= 0, "must be an integer >= 0"),
        ),
        null_action=s.opt("null_action", None, flag),
        keep_best=s.opt("keep_best", None, flag),
        control_cost=s.opt(
            "control_cost",
            None,
            _checked(lambda v: _real(v) and 0 <= v < math.inf, "must be finite and >= 0"),
        ),
        seed=s.opt("seed", None, _checked(lambda v: isinstance(v, int), "must be an integer")),
    )
    s.done()
    _check_together(s, cfg, samples)
    return cfg


def _check_together(s: Section, cfg: MppiSettings, samples: int) -> None:
    """What one key alone cannot tell: the lower bounds below the upper ones, finite when
    squashing; η_l reachable with ``samples`` per mode; the Savitzky-Golay order below
    its window."""
    if cfg.u_min is not None and cfg.u_max is not None:  # one alone: the other is the model's
        if len(cfg.u_min) != len(cfg.u_max) or not all(
            lo < hi for lo, hi in zip(cfg.u_min, cfg.u_max)
        ):
            raise s.error("u_max", "must be above u_min, channel by channel", list(cfg.u_max))
        if cfg.bound == "squash" and not all(map(math.isfinite, cfg.u_min + cfg.u_max)):
            raise s.error("bound", "squash needs finite u_min and u_max", cfg.bound, "clamp")
    if cfg.eta_bounds is not None and cfg.eta_bounds[0] > samples:
        raise ConfigError(
            s.source,
            s.key_path("eta_bounds"),
            f"eta_l cannot be reached with planner.samples = {samples} "
            "per mode: eta counts the samples that carry weight",
            list(cfg.eta_bounds),
            f"eta_l <= {samples}",
        )
    window = cfg.savgol_window or 0
    if window and (cfg.savgol_order if cfg.savgol_order is not None else 2) >= window:
        raise s.error("savgol_order", "must be below savgol_window", cfg.savgol_order)
