"""The soak's verdicts and its report (:mod:`scripts.measure.soak_episodes` runs it): pure checks
of what the soak did (its faults) against what the logs say (each world's steps, each planner's
memory), and the reliability table of docs/reliability.md regenerated from a results file."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import typer

from m3p2i.blocks import read_results, regenerate

if TYPE_CHECKING:
    from .soak import Fault, SoakConfig

MIB = 1024 * 1024
# a wrong-session command carries this control, so that the log proves it was never applied
FORGED_CTRL = (0.123456, -0.654321)


def stale_steps(steps: list[dict], timeout: float) -> list[dict]:
    """Steps driven by a command (not the safe control) chosen more than ``timeout`` s after
    the newest command arrived: what the watchdog must never let through."""
    return [
        s
        for s in steps
        if not s.get("safe") and (s.get("cmd_age") is None or s["cmd_age"] > timeout)
    ]


def outage_violations(steps: list[dict], start: float, end: float) -> tuple[int, list[dict]]:
    """Steps logged between ``start`` and ``end`` (wall): how many, and those not safe."""
    inside = [s for s in steps if start <= s["wall"] < end]
    return len(inside), [s for s in inside if not s.get("safe")]


def first_driven_after(steps: list[dict], since: float) -> dict | None:
    """The first step driven by a command that arrived at or after ``since`` (wall)."""
    for s in steps:
        if not s.get("safe") and s.get("cmd_age") is not None and s["wall"] - s["cmd_age"] >= since:
            return s
    return None


def _after_cuts(faults: list[Fault], driven: list[dict], window: float = 5.0) -> str:
    """For the cut row: how old the states were that the plans driving the robot in the
    ``window`` s after each link's return were made from (the step record's ``age``). Measured,
    not checked: a TCP stream that held states through the cut can deliver them that late
    (the world times a command from its arrival, so ``cmd_age`` does not show it)."""
    back = [f.resumed for f in faults if f.kind == "cut" and f.resumed is not None]
    ages = [s.get("age") or 0.0 for s in driven if any(b <= s["wall"] < b + window for b in back)]
    if not ages:
        return ""
    return (
        f"; in the {window:g} s after the link's return the driving plans came from states "
        f"{np.median(ages):.2f} s old (median, max {max(ages):.2f} s)"
    )


def is_forged(ctrl: list[float]) -> bool:
    """Whether a step's control is the one only wrong-session commands carried."""
    n = min(len(ctrl), len(FORGED_CTRL))
    return bool(np.allclose(ctrl[:n], FORGED_CTRL[:n], rtol=0, atol=1e-9))


def rss_growth(samples: list[tuple[float, int]], since: float | None) -> float | None:
    """MiB from the first sample at or after ``since`` to the last; None without two."""
    if since is None:
        return None
    after = [b for t, b in samples if t >= since]
    if len(after) < 2:
        return None
    return (after[-1] - after[0]) / MIB


@dataclass
class Check:
    name: str
    ok: bool
    detail: str


# what each kind of fault must be followed by, in the order the checks are listed
_RECOVERIES = {
    "kill": "killed planner replaced",
    "restart": "planner found the restarted world",
    "pause": "paused planner resumed",
    "flood": "planner drove on after a flood",
    "cut": "planner drove again after a link cut",
}


def evaluate(
    cfg: SoakConfig,
    faults: list[Fault],
    worlds: list[dict],
    planners: list[dict],
    floods_sent: dict,
) -> list[Check]:
    """The soak's verdicts from what it did (``faults``) and what the logs say (``worlds``:
    per world process its records, exit code and whether it was stopped on purpose)."""
    all_steps = [s for w in worlds for s in w["steps"]]
    driven = [s for s in all_steps if not s.get("safe")]
    return [
        _stale_check(cfg, all_steps, driven),
        _outage_check(cfg, faults, all_steps),
        *(
            _recovery_check(cfg, kind, faults, driven, worlds)
            for kind in sorted(cfg.kinds, key=list(_RECOVERIES).index)
        ),
        _died_check(worlds),
        _logs_check(worlds),
        _garbage_check(all_steps, worlds, floods_sent),
        _memory_check(cfg, planners + worlds),
    ]


def _stale_check(cfg: SoakConfig, all_steps: list[dict], driven: list[dict]) -> Check:
    """No step driven by a command older than the world's command time-out."""
    stale = stale_steps(all_steps, cfg.command_timeout)
    worst = max((s["cmd_age"] for s in driven if s.get("cmd_age") is not None), default=0.0)
    return Check(
        "no stale command applied",
        not stale and bool(driven),
        f"{len(stale)} of {len(driven)} driven steps had a command older than "
        f"{cfg.command_timeout:g} s (oldest driving: {worst:.3f} s)",
    )


def _outage_check(cfg: SoakConfig, faults: list[Fault], all_steps: list[dict]) -> Check:
    """Only safe steps while a planner was down, from its time-out until it recovered."""
    held, bad, windows = 0, [], 0
    for f in faults:
        if f.outage is None:
            continue
        windows += 1
        end = f.recovered if f.recovered is not None else time.time()
        n, v = outage_violations(all_steps, f.outage + cfg.command_timeout + cfg.slack, end)
        held += n
        bad += v
    return Check(
        "safe control while the planner was down",
        not bad and (held > 0 or not windows),
        f"{held} steps logged in {windows} outages (from fault + "
        f"{cfg.command_timeout:g} s + {cfg.slack:g} s), {len(bad)} not safe",
    )


def _recovery_check(
    cfg: SoakConfig, kind: str, faults: list[Fault], driven: list[dict], worlds: list[dict]
) -> Check:
    """Every fault of ``kind`` recovered from within the takeover bound."""
    mine = [f for f in faults if f.kind == kind]
    times = [f.recovery for f in mine if f.recovery is not None]
    late = [f for f in mine if f.recovery is None or f.recovery > cfg.takeover]
    worst_s = f"max {max(times):.2f} s" if times else "none measured"
    detail = f"{len(mine) - len(late)}/{len(mine)} ({worst_s})" + _after_cuts(mine, driven)
    if kind == "restart":
        detail += _cold_starts(worlds)
    return Check(f"{_RECOVERIES[kind]} within {cfg.takeover:g} s", not late, detail)


def _cold_starts(worlds: list[dict]) -> str:
    """For the restart row: how long a new world takes to serve, which its recovery (timed
    from the world's serving) leaves out; empty when no world measured it."""
    cold = [w["serving_after_s"] for w in worlds if w.get("serving_after_s") is not None]
    if not cold:
        return ""
    return (
        f" from its serving; a new world serves {np.median(cold):.2f} s "
        f"(median, max {max(cold):.2f} s) after its start"
    )


def _died_check(worlds: list[dict]) -> Check:
    """Every world process ended with its episode or by the soak's deliberate stop."""
    died = [w for w in worlds if not w["stopped_on_purpose"] and w["returncode"] not in (0, 1)]
    return Check(
        "the world never died",
        not died,
        f"{len(worlds)} world processes, {len(died)} ended otherwise than by "
        f"their episode's end or the deliberate stop"
        + (f" (codes {[w['returncode'] for w in died]})" if died else ""),
    )


def _logs_check(worlds: list[dict]) -> Check:
    """Every episode log parses, from its header to its summary."""
    incomplete = [w["log"] for w in worlds if not w["complete"]]
    return Check(
        "every episode log complete with its summary",
        not incomplete and bool(worlds),
        f"{len(worlds) - len(incomplete)}/{len(worlds)} logs parse, start with the "
        f"header and end with the summary (steps = summary.steps)"
        + (f"; not: {incomplete[:3]}" if incomplete else ""),
    )


def _garbage_check(all_steps: list[dict], worlds: list[dict], floods_sent: dict) -> Check:
    """The floods' frames rejected by the worlds, and no forged control ever applied."""
    forged = [s for s in all_steps if is_forged(s["ctrl"])]
    rejected = sum(w["rejected"] for w in worlds)
    expected = floods_sent.get("rejectable", 0)
    return Check(
        "garbage rejected, none applied",
        not forged and rejected >= expected,
        f"{floods_sent.get('frames', 0)} frames in {floods_sent.get('floods', 0)} "
        f"floods: {rejected} logged as rejected (>= {expected} expected), "
        f"{floods_sent.get('wrong_session', 0)} of a wrong session, "
        f"{len(forged)} steps with a forged control",
    )


def _memory_check(cfg: SoakConfig, processes: list[dict]) -> Check:
    """Each role's processes grew their resident memory by at most the bound."""
    growths = {}
    for p in processes:
        g = p.get("rss_growth")
        if g is not None:
            growths.setdefault(p["role"], []).append(g)
    over = {r: max(g) for r, g in growths.items() if max(g) > cfg.rss_bound}
    text = (
        ", ".join(
            f"{r}: max {max(g):+.1f} MiB over {len(g)} processes"
            for r, g in sorted(growths.items())
        )
        or "no process lived long enough"
    )
    return Check(
        f"memory growth <= {cfg.rss_bound:g} MiB per process",
        not over and "planner" in growths,
        text,
    )


def markdown(results: dict, source: str) -> str:
    """The reliability table of docs/reliability.md, from a results file."""
    lines = ["| check | holds | measured |", "|---|:---:|---|"]
    for c in results["checks"]:
        lines.append(f"| {c['name']} | {'yes' if c['ok'] else '**no**'} | {c['detail']} |")
    faults = ", ".join(f"{k} {v['survived']}/{v['injected']}" for k, v in results["faults"].items())
    episodes = ", ".join(f"{n} {s}" for s, n in sorted(results["episodes"].items()))
    cfg = results["config"]
    lines += [
        "",
        f"Faults survived/injected: {faults}. Episodes ({cfg['scenario']}, real time, "
        f"{len(results['worlds'])} world processes, {results['steps']} steps): {episodes} "
        f"(`stopped`: the deliberate world restarts and the end of the run). "
        f"`{results['command']}`, {results['date']}, {results['wall_s']:.0f} s of wall "
        f"time on {results['machine']} (seed {cfg['seed']}); from `{source}`.",
    ]
    return "\n".join(lines)


def update(text: str, base: Path) -> str:
    """``text`` with every ``<!-- soak PATH -->`` block regenerated from its results file."""
    new, n = regenerate(
        text,
        "soak",
        "soak",
        lambda path: markdown(read_results(base / path, f"<!-- soak {path} -->"), path) + "\n",
    )
    if not n:
        raise typer.BadParameter(
            "no '<!-- soak PATH -->' ... '<!-- end of soak -->' block found", param_hint="--update"
        )
    return new


def print_table(results: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table("check", "holds", "measured", title="soak: " + results["command"])
    for c in results["checks"]:
        table.add_row(c["name"], "yes" if c["ok"] else "NO", c["detail"])
    console = Console(width=160)
    console.print(table)
    console.print(
        "faults survived/injected: "
        + ", ".join(f"{k} {v['survived']}/{v['injected']}" for k, v in results["faults"].items())
    )
    console.print(
        f"episodes: {results['episodes']}; {results['steps']} steps; {results['wall_s']:.0f} s"
    )
