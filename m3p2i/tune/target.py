"""What a study tunes: a scenario or a bench case, its variants for a set of values, the original's
own values, and the overlay that holds the best set."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from m3p2i import bench as B
from m3p2i.tune.space import MISSING, Space, get_key, key_parts, set_key
from shared.config import ConfigError
from shared.config_files import entries
from shared.scenario import Scenario, find_scenario, load_scenario, parse_scenario


@dataclass(frozen=True)
class Target:
    """What is tuned: a bench case (its mode, faults, plan rate) and its scenario."""

    case: B.BenchCase
    scenario: Scenario
    base: str  # what the overlay's base: names: a scenario name, or an absolute path
    timeout: float  # wall-clock seconds per trial
    label: str  # for the report


def resolve_target(spec: str, timeout: float | None = None) -> Target:
    """``BENCH:CASE`` (a case of a bench file), a scenario (name or path; a lock-step case of its
    own), else a case name of one of the bench files (``m3p2i list bench``)."""
    bench, sep, case = spec.rpartition(":")
    if sep and bench:
        return _case_target(B.load_bench(bench), case, timeout)
    try:
        path = find_scenario(spec)
    except ConfigError:
        found = []
        for e in entries("bench"):
            if e.shadowed_by is not None:
                continue
            try:
                cfg = B.load_bench(e.path)
            except ConfigError:
                continue
            if any(c.case == spec for c in cfg.cases):
                found.append(cfg)
        if len(found) != 1:
            why = "no scenario or bench case of this name" if not found else "a case of several"
            raise ConfigError(
                spec,
                "",
                why + (f" bench files ({', '.join(c.source for c in found)})" if found else ""),
                expected="a scenario (m3p2i list), a case name, or BENCH:CASE",
            ) from None
        return _case_target(found[0], spec, timeout)
    scenario = load_scenario(path)
    case = B.BenchCase(case=scenario.name, variant="", scenario=str(path.resolve()), trials=1)
    base = spec if not Path(spec).is_file() else str(path.resolve())
    return Target(case, scenario, base, timeout or 600.0, f"scenario {scenario.name}, lockstep")


def _case_target(cfg: B.BenchConfig, name: str, timeout: float | None) -> Target:
    case = next((c for c in cfg.cases if c.case == name), None)
    if case is None:
        raise ConfigError(
            cfg.source, "cases", "no such case", name, ", ".join(c.case for c in cfg.cases)
        )
    local = Path(cfg.source).parent / case.scenario
    path = local if local.is_file() else find_scenario(case.scenario)
    base = str(path.resolve()) if local.is_file() else case.scenario
    case = dataclasses.replace(case, scenario=str(path.resolve()))
    return Target(
        case,
        load_scenario(path),
        base,
        timeout or cfg.timeout,
        f"case {name} of {cfg.source} ({case.mode_label})",
    )


def values_id(values: dict[str, Any]) -> str:
    """A short name for a parameter set: the hash of its values."""
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:8]


def variant_raw(target: Target, space: Space, values: dict[str, Any]) -> dict:
    """The target's scenario mapping with ``values`` set, read by the scenario loader (its
    error names the scenario file, the space file and the values)."""
    raw = copy.deepcopy(target.scenario.raw)
    for key, value in values.items():
        set_key(raw, key, value, space.source)
    raw.setdefault("name", target.scenario.name)
    shown = ", ".join(f"{k}={json.dumps(v)}" for k, v in values.items())
    parse_scenario(raw, f"{target.scenario.source} with {space.source} ({shown})")
    return raw


def write_variant(target: Target, space: Space, values: dict[str, Any], folder: Path) -> Scenario:
    """``variant_raw`` written to ``folder/ID/NAME.yaml`` (both processes load it) and loaded."""
    raw = variant_raw(target, space, values)
    out = folder / values_id(values) / f"{target.scenario.name}.yaml"
    out.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(raw, sort_keys=False)
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)
    return load_scenario(out)


def check_space(
    target: Target,
    space: Space,
    folder: Path,
    process_check: Callable[[str], list[str]] | None = None,
) -> list[str]:
    """Every end of every key read by the scenario loader (raises its ConfigError); then the
    two corners of the space (all keys low, all keys high) checked by ``process_check`` (both
    processes' ``--check``: what only they resolve, MPPI keys and cost-term parameters).
    Returns the processes' messages, empty when the space is sound."""
    for p in space.params:
        for end in p.ends():
            variant_raw(target, space, {p.key: end})
    if process_check is None:
        return []
    corners = [{p.key: p.ends()[i] for p in space.params} for i in (0, 1)]
    messages = []
    for values in corners:
        scenario = write_variant(target, space, values, folder)
        shown = ", ".join(f"{k}={json.dumps(v)}" for k, v in values.items())
        messages += [f"{space.source} ({shown}): {m}" for m in process_check(scenario.source)]
    return messages


def baseline(target: Target, space: Space) -> dict[str, Any] | None:
    """The original's values as Optuna parameters, when the scenario sets every key inside the
    space; else None."""
    out = {}
    for p in space.params:
        v = p.encode(get_key(target.scenario.raw, p.key))
        if v is MISSING:
            return None
        out[p.key] = v
    return out


def overlay(target: Target, space: Space, values: dict[str, Any]) -> dict:
    """A scenario of ``base:`` the target plus the tuned keys. A key inside a list carries the
    whole list (a base's list is replaced, not merged), with the tuned items set."""
    tuned = variant_raw(target, space, values)
    out: dict = {
        "base": target.base,
        "name": f"{target.scenario.name}_tuned",
        "description": f"{target.scenario.name} with the parameters m3p2i tune found "
        f"({Path(space.source).name})",
    }
    for key in values:
        parts = key_parts(key)
        cut = next((i for i, p in enumerate(parts) if isinstance(p, int)), len(parts))
        head = parts[:cut]
        node = out
        for part in head[:-1]:
            node = node.setdefault(part, {})
        node[head[-1]] = copy.deepcopy(get_key(tuned, ".".join(map(str, head))))
    return out


def write_overlay(target: Target, space: Space, values: dict[str, Any], out: Path) -> Path:
    path = out / "overlay.yaml"
    header = (
        f"# Written by m3p2i tune: {target.label}; space {space.source}.\n"
        f"# Run it: m3p2i run {path}{run_options(target.case)}\n"
    )
    path.write_text(header + yaml.safe_dump(overlay(target, space, values), sort_keys=False))
    load_scenario(path)  # what the user runs must load
    return path


def run_options(case: B.BenchCase) -> str:
    """The ``m3p2i run`` options that reproduce the case's conditions."""
    opts = [f"--mode {case.mode}"] if case.mode != "lockstep" else []
    if case.plan_every > 1:
        opts.append(f"--plan-every {case.plan_every}")
    if case.max_rate:
        opts.append(f"--planner-max-rate {case.max_rate:g}")
    if case.realtime_factor != 1.0:
        opts.append(f"--realtime-factor {case.realtime_factor:g}")
    if case.faults:
        opts.append(f"--faults {case.faults}")
    if case.measure_delays:
        opts.append("--measure-delays")
    elif case.delays is not None:
        opts.append("--compensate")
    return (" " + " ".join(opts)) if opts else ""
