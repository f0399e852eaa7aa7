"""Parameter sweeps of ``m3p2i bench``: ``--set KEY=V1,V2,...`` (repeatable) or a ``sweep:``
section of a bench file runs every case once per combination of the values.

A key is a dotted path into the scenario file (``planner.samples``, ``planner.mppi.alpha_u``);
a value is read as YAML (``50``, ``0.5``, ``true``, ``[0.1, 0.2]``). Each combination is applied to
the scenario's YAML mapping and read by the scenario loader, so a misspelt key or a bad value is
the loader's usual error (file, key, value, what was expected) before any trial starts; the
variant's hash is that of its own content, so resuming a sweep works as for any bench.

The summary of a sweep has one table per swept key (success and time against the value, per
case, over the other keys' values) and one plot per key.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from shared.config import ConfigError

# results.csv column of a row's overrides: JSON {key: value}, empty without a sweep
OVERRIDES = "overrides"


@dataclass(frozen=True)
class Sweep:
    """Swept keys in order, each with its values; empty: no sweep."""

    keys: tuple[tuple[str, tuple[Any, ...]], ...] = ()

    def variants(self) -> list[dict[str, Any]]:
        """Every combination, the last key varying fastest; ``[{}]`` without a sweep."""
        if not self.keys:
            return [{}]
        names = [k for k, _ in self.keys]
        return [dict(zip(names, combo)) for combo in itertools.product(*(v for _, v in self.keys))]

    def merged(self, other: Sweep) -> Sweep:
        """This sweep with ``other``'s keys replacing or added (``--set`` over the file's)."""
        keys = dict(self.keys)
        keys.update(dict(other.keys))
        return Sweep(tuple(keys.items()))


def split_values(text: str) -> list[str]:
    """``a,[1, 2],{x: 1}`` -> ``['a', '[1, 2]', '{x: 1}']``: commas inside brackets or quotes
    belong to a value."""
    parts, depth, quote, cur = [], 0, "", []
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur).strip())
    return parts


def parse_set(items: Iterable[str], source: str = "--set") -> Sweep:
    """``["planner.samples=50,100", ...]`` -> a :class:`Sweep`; each value read as YAML."""
    keys: dict[str, tuple[Any, ...]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ConfigError(
                source, "", "not KEY=VALUE[,VALUE...]", item, "e.g. planner.samples=50,100,200"
            )
        parsed = []
        for v in split_values(values):
            try:
                parsed.append(yaml.safe_load(v) if v else None)
            except yaml.YAMLError as exc:
                raise ConfigError(source, key, f"a value is not YAML: {exc}", v) from None
        keys[key] = tuple(_unique(parsed))
    return Sweep(tuple(keys.items()))


def parse_sweep_section(data: Any, source: str) -> Sweep:
    """A bench file's ``sweep: {KEY: [V1, V2, ...], ...}``."""
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(
            source,
            "sweep",
            "a mapping of scenario keys to lists of values",
            data,
            "e.g. {planner.samples: [50, 100, 200]}",
        )
    keys = []
    for key, values in data.items():
        if not isinstance(key, str) or not isinstance(values, list) or not values:
            raise ConfigError(
                source, f"sweep.{key}", "a non-empty list of values", values, "e.g. [50, 100, 200]"
            )
        keys.append((key, tuple(_unique(values))))
    return Sweep(tuple(keys))


def _unique(values: list) -> list:
    out: list = []
    for v in values:
        if v not in out:
            out.append(v)
    return out


def apply_overrides(raw: dict, overrides: Mapping[str, Any]) -> dict:
    """A deep copy of the scenario mapping ``raw`` with each dotted key set; missing mappings on
    the way are created (the loader then says whether the key is one it knows)."""
    out = copy.deepcopy(raw)
    for key, value in overrides.items():
        node = out
        parts = key.split(".")
        for i, part in enumerate(parts[:-1]):
            child = node.get(part) if isinstance(node, dict) else None
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(
                    "--set",
                    key,
                    f"{'.'.join(parts[: i + 1])} is not a mapping",
                    child,
                    "a key path through mappings",
                )
            node = child
        node[parts[-1]] = copy.deepcopy(value)
    return out


def label(overrides: Mapping[str, Any]) -> str:
    """``samples=50, horizon=10``: overrides for a file name or a title (last path part)."""
    return ", ".join(f"{k.rsplit('.', 1)[-1]}={_show(v)}" for k, v in overrides.items())


def file_label(overrides: Mapping[str, Any]) -> str:
    """Overrides as a file-name-safe suffix."""
    text = "_".join(f"{k}={_show(v)}" for k, v in overrides.items())
    return "".join(c if c.isalnum() or c in "._=-" else "-" for c in text)


def _show(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def to_cell(overrides: Mapping[str, Any]) -> str:
    """The results.csv cell: JSON, keys in sweep order; empty without overrides."""
    return json.dumps(dict(overrides)) if overrides else ""


def from_cell(cell: str | None) -> dict[str, Any]:
    """A results.csv overrides cell back to {key: value}."""
    return json.loads(cell) if cell else {}


def variant_case(row: Mapping[str, str]) -> str:
    """A row's case with its overrides, ``push (samples=50)``: a sweep variant's table row."""
    ov = from_cell(row.get(OVERRIDES))
    return f"{row['case']} ({label(ov)})" if ov else row["case"]


# ------------------------------------------------------------------------------------- summary


@dataclass(frozen=True)
class SweepPoint:
    """One (case, value of one key) cell of a sweep table, over the other keys' values."""

    case: str
    value: Any
    trials: int
    successes: int
    time: tuple[float, float] | None  # mean, std over the successful trials
    planner_hz: float | None
    collisions: float | None = None  # mean over the trials that ended by themselves


def swept_keys(rows: list[dict[str, str]]) -> list[str]:
    """The keys the rows' overrides set, in first-seen order."""
    keys: dict[str, None] = {}
    for r in rows:
        keys.update(dict.fromkeys(from_cell(r.get(OVERRIDES))))
    return list(keys)


def sweep_points(rows: list[dict[str, str]], key: str) -> list[SweepPoint]:
    """Per case (first-seen order) and value of ``key`` (sorted when all are numbers)."""
    groups: dict[tuple[str, str], list[dict[str, str]]] = {}
    values: dict[str, Any] = {}
    for r in rows:
        ov = from_cell(r.get(OVERRIDES))
        if key not in ov:
            continue
        vkey = json.dumps(ov[key], sort_keys=True)
        values[vkey] = ov[key]
        groups.setdefault((r["case"], vkey), []).append(r)
    cases = list(dict.fromkeys(c for c, _ in groups))
    order = list(values)
    if all(_is_number(values[v]) for v in order):
        order.sort(key=lambda v: values[v])
    out = []
    for case in cases:
        for v in order:
            mine = groups.get((case, v))
            if not mine:
                continue
            won = [r for r in mine if r["success"] == "1" and not r["reason"]]
            times = [float(r["time"]) for r in won if r["time"]]
            hz = [float(r["planner_hz"]) for r in mine if r["planner_hz"] and not r["reason"]]
            hits = [float(r["collisions"]) for r in mine if r.get("collisions") and not r["reason"]]
            time = None
            if times:
                mean = sum(times) / len(times)
                time = (mean, math.sqrt(sum((t - mean) ** 2 for t in times) / len(times)))
            out.append(
                SweepPoint(
                    case,
                    values[v],
                    len(mine),
                    len(won),
                    time,
                    sum(hz) / len(hz) if hz else None,
                    sum(hits) / len(hits) if hits else None,
                )
            )
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


SWEEP_HEADERS = (
    "case",
    "value",
    "trials",
    "success (95 % interval)",
    "time [s]",
    "collisions",
    "planner Hz",
)


def sweep_table(points: list[SweepPoint], key: str) -> str:
    """Markdown table of one key's points."""
    from m3p2i.bench_report import wilson

    head = ("case", key, *SWEEP_HEADERS[2:])
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    for p in points:
        lo, hi = wilson(p.successes, p.trials)
        time = f"{p.time[0]:.2f} ({p.time[1]:.2f})" if p.time else "—"
        hz = f"{p.planner_hz:.1f}" if p.planner_hz is not None else "—"
        hits = f"{p.collisions:.2f}" if p.collisions is not None else "—"
        lines.append(
            f"| {p.case} | {_show(p.value)} | {p.trials} | {p.successes}/{p.trials} "
            f"({100 * lo:.0f}-{100 * hi:.0f} %) | {time} | {hits} | {hz} |"
        )
    return "\n".join(lines)


SWEEP_LEGEND = (
    "Per case and value of the swept key, over the seeds (and the other swept keys' "
    "values): success with its 95 % Wilson interval; time: mean (std) simulated "
    "seconds to success, over the successful trials; collisions: mean contacts per trial "
    "with what the scenario's metric counts (the moving obstacle), over the trials "
    "that ended by themselves (— : not measured); planner Hz: mean planner "
    "iterations per wall-clock second."
)


def sweep_report(rows: list[dict[str, str]]) -> str:
    """Markdown: one table per swept key, and the legend."""
    parts = []
    for key in swept_keys(rows):
        parts += [f"`{key}`:", "", sweep_table(sweep_points(rows, key), key), ""]
    return "\n".join(parts + [SWEEP_LEGEND]) + "\n"


def plot_sweep(rows: list[dict[str, str]], folder: Path) -> list[Path]:
    """One PNG per swept key in ``folder`` (``sweep-KEY.png``): success rate and time to
    success against the value, one line per case. Needs matplotlib (``m3p2i[plots]``)."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no display needed
    import matplotlib.pyplot as plt

    written = []
    folder.mkdir(parents=True, exist_ok=True)
    for key in swept_keys(rows):
        points = sweep_points(rows, key)
        numeric = all(_is_number(p.value) for p in points)
        fig, (ax_s, ax_t) = plt.subplots(1, 2, figsize=(10, 3.8))
        for case in dict.fromkeys(p.case for p in points):
            mine = [p for p in points if p.case == case]
            xs = [p.value if numeric else _show(p.value) for p in mine]
            ax_s.plot(xs, [100 * p.successes / p.trials for p in mine], "o-", label=case)
            timed = [(x, p.time) for x, p in zip(xs, mine) if p.time]
            if timed:
                ax_t.errorbar(
                    [x for x, _ in timed],
                    [t[0] for _, t in timed],
                    yerr=[t[1] for _, t in timed],
                    fmt="o-",
                    capsize=3,
                    label=case,
                )
        positive = numeric and all(p.value > 0 for p in points)
        for ax in (ax_s, ax_t):
            if positive and max(p.value for p in points) / min(p.value for p in points) >= 8:
                ax.set_xscale("log")  # samples 25..800: equal steps for doublings
                ax.set_xticks(sorted({p.value for p in points}))
                ax.set_xticklabels([_show(v) for v in sorted({p.value for p in points})])
                ax.minorticks_off()
            ax.set_xlabel(key)
            ax.grid(alpha=0.3)
        ax_s.set_ylabel("success [%]")
        ax_s.set_ylim(-5, 105)
        ax_t.set_ylabel("time to success [s] (mean, std)")
        ax_s.legend(fontsize=8)
        trials = sorted({p.trials for p in points})
        fig.suptitle(f"sweep of {key} ({'/'.join(map(str, trials))} trials per point)")
        fig.tight_layout()
        path = folder / f"sweep-{''.join(c if c.isalnum() or c in '._-' else '-' for c in key)}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written
