"""Did the planner keep up? Plan ages and steps per plan, from an episode log's step records.

Each step record names the state its control was planned from (``plan_seq``, -1 for the safe
control) and the control's ``age``: world seconds since that state. In lock-step every plan serves
one step at age 0; in real time a planner at a third of the world's rate serves about three steps
per plan with ages of one to three steps plus the transport delay. Logs written before these
fields existed give ``None``.
"""

from __future__ import annotations

import numpy as np

from server.evaluation.log_reader import steps as step_records


def timing_summary(records: list[dict]) -> dict | None:
    """``plans`` (distinct plans that drove a step), ``steps_per_plan`` (mean, max), ``age_ms``
    (mean, p95, max over planned steps) and ``safe_steps`` (steps on the safe control)."""
    steps = [s for s in step_records(records) if "plan_seq" in s]
    if not steps:
        return None
    sources = np.array([s["plan_seq"] for s in steps])
    planned = sources >= 0
    ages = np.array([s["age"] for s in steps])[planned] * 1000.0
    # a plan's run: consecutive steps driven by the same source
    runs = np.diff(np.flatnonzero(np.r_[True, sources[1:] != sources[:-1], True]))
    firsts = sources[np.r_[0, np.cumsum(runs)[:-1]]]
    plan_runs = runs[firsts >= 0]
    return {
        "plans": int(plan_runs.size),
        "steps_per_plan": _mean_max(plan_runs),
        "age_ms": (
            {
                "mean": float(ages.mean()),
                "p95": float(np.percentile(ages, 95)),
                "max": float(ages.max()),
            }
            if ages.size
            else None
        ),
        "safe_steps": int((~planned).sum()),
        "steps": len(steps),
    }


def _mean_max(values: np.ndarray) -> dict | None:
    return {"mean": float(values.mean()), "max": int(values.max())} if values.size else None


def describe_timing(timing: dict | None) -> str:
    """One line for people: ``412 plans, 3.4 steps each (max 7), age 31 ms (p95 45, max 60),
    0 safe steps``."""
    if not timing:
        return "no timing in this log"
    parts = [f"{timing['plans']} plans"]
    if timing["steps_per_plan"]:
        spp = timing["steps_per_plan"]
        parts.append(f"{spp['mean']:.1f} steps each (max {spp['max']})")
    if timing["age_ms"]:
        age = timing["age_ms"]
        parts.append(f"age {age['mean']:.0f} ms (p95 {age['p95']:.0f}, max {age['max']:.0f})")
    parts.append(f"{timing['safe_steps']} of {timing['steps']} steps on the safe control")
    return ", ".join(parts)
