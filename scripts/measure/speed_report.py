"""The speed table of docs/speed.md: ``python scripts/benchmark.py --report FILE --update
docs/speed.md`` regenerates its ``<!-- benchmark PATH -->`` blocks that name FILE (without
``--report``: every block) from the results files that ``scripts/benchmark.py --out`` writes
(median and range over the runs), so the table is never typed by hand."""

from __future__ import annotations

import statistics
from pathlib import Path

import typer

from m3p2i.blocks import read_results, regenerate


def spread(values: list[float], digits: int) -> str:
    """``median (min-max)`` of a figure over the runs; the median alone for one run."""
    med = f"{statistics.median(values):.{digits}f}"
    if len(values) == 1:
        return med
    return f"{med} ({min(values):.{digits}f}-{max(values):.{digits}f})"


def markdown(results: dict, source: str) -> str:
    """The speed table of a results file (``--out``): one row per case, median and range over
    its runs, then how and where it was measured."""
    cases: dict[tuple, list[dict]] = {}
    for row in results["rows"]:
        cases.setdefault((row["scenario"], row["samples"], row["horizon"]), []).append(row)
    lines = [
        "| scenario | samples × horizon × step | planner Hz | iteration ms | ratio to the "
        "world's rollout | ratio to its own rollout | to its own + sensors |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for (name, samples, horizon), rows in cases.items():
        col = lambda key, rows=rows: [r[key] for r in rows]  # noqa: E731 - one table's columns
        lines.append(
            f"| `{name}` | {samples} × {horizon} × {rows[0]['planning_step']:g} s | "
            f"{spread(col('hz'), 1)} | {spread(col('iteration_ms'), 2)} | "
            f"{spread(col('ratio_to_rollout'), 2)} | "
            f"{spread(col('ratio_to_own_rollout'), 2)} | "
            f"{spread(col('ratio_to_sensor_rollout'), 2)} |"
        )
    lines += perception(results)
    lines += phase_split(results)
    lines += rest_floor(results)
    lines += [
        "",
        f"Median (min-max) over {results['runs']} runs of `{results['command']}`, "
        f"{results['date']}, {results['machine']}"
        + (f" ({results['versions']})" if results.get("versions") else "")
        + f", {results['threads']} rollout threads, "
        f"median of {results['iterations']} iterations per run; from `{source}`.",
    ]
    return "\n".join(lines)


# a scenario that sees its obstacles only through sensors -> the same obstacles declared
DECLARED = {"navigation_seen": "navigation_clear"}


def perception(results: dict) -> list[str]:
    """The map's figures of the cases with sensors (their rows carry ``map_*``), and each
    one's iteration against the same obstacles declared (:data:`DECLARED`), run by run; no
    lines for a file without such cases."""
    by_run: dict[tuple, dict] = {}
    for row in results["rows"]:
        by_run[(row["scenario"], row.get("run", 0))] = row
    seen = sorted({name for (name, _), row in by_run.items() if "map_update_ms" in row})
    if not seen:
        return []
    lines = [
        "",
        "| scenario | iteration ms | against its obstacles declared | map update ms | "
        "map updates / s | share of a core |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in seen:
        rows = [r for (n, _), r in by_run.items() if n == name]
        ref = DECLARED.get(name)
        ratios = [
            r["iteration_ms"] / by_run[(ref, r.get("run", 0))]["iteration_ms"]
            for r in rows
            if (ref, r.get("run", 0)) in by_run
        ]
        against = f"{spread(ratios, 2)} × `{ref}`" if ratios else "–"
        col = lambda key, rows=rows: [r[key] for r in rows]  # noqa: E731 - one table's columns
        lines.append(
            f"| `{name}` | {spread(col('iteration_ms'), 2)} | {against} | "
            f"{spread(col('map_update_ms'), 2)} | {rows[0]['map_rate_hz']:g} | "
            f"{spread(col('map_core_share'), 3)} |"
        )
    return lines


def phase_split(results: dict) -> list[str]:
    """Where an iteration's time goes (``phases_ms``): per case the median over the runs of
    each phase's median ms per iteration, and its share of their sum; no lines for a file
    without the split."""
    cases: dict[str, list[dict]] = {}
    for row in results["rows"]:
        if "phases_ms" in row:
            cases.setdefault(row["scenario"], []).append(row["phases_ms"])
    if not cases:
        return []
    phases = list(dict.fromkeys(p for runs in cases.values() for r in runs for p in r))
    lines = [
        "",
        "| scenario | " + " | ".join(phases) + " |",
        "|---|" + "---:|" * len(phases),
    ]
    for name, runs in cases.items():
        med = {p: statistics.median(r.get(p, 0.0) for r in runs) for p in phases}
        total = sum(med.values()) or 1.0
        cells = [f"{med[p]:.3f} ({100 * med[p] / total:.0f} %)" for p in phases]
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return lines


def rest_floor(results: dict) -> list[str]:
    """Per case, the rest of an iteration (every phase but the rollout; median over the runs
    of the sum of the phase medians) as measured, and with its rollout replayed
    (``phases_replayed_ms``); no lines for a file without the replayed split."""
    cases: dict[str, list[dict]] = {}
    for row in results["rows"]:
        if "phases_replayed_ms" in row:
            cases.setdefault(row["scenario"], []).append(row)
    if not cases:
        return []
    lines = [
        "",
        "| scenario | all but the rollout, ms | the same, its rollout replayed | rollout, ms |",
        "|---|---:|---:|---:|",
    ]
    for name, rows in cases.items():
        rest = [rest_ms(r["phases_ms"]) for r in rows]
        floor = [rest_ms(r["phases_replayed_ms"]) for r in rows]
        rollout = [r["phases_ms"].get("rollout", 0.0) for r in rows]
        lines.append(
            f"| `{name}` | {spread(rest, 2)} | {spread(floor, 2)} | {spread(rollout, 2)} |"
        )
    return lines


def rest_ms(phases: dict[str, float]) -> float:
    """Milliseconds of every phase but the rollout."""
    return sum(v for k, v in phases.items() if k != "rollout")


def update(text: str, base: Path, only: Path | None = None) -> str:
    """``text`` with every ``<!-- benchmark PATH -->`` block regenerated from its results file
    (PATH relative to ``base``); with ``only``, just the blocks that name that file."""
    named: list[str] = []

    def render(path: str) -> str | None:
        named.append(path)
        if only is not None and (base / path).resolve() != only.resolve():
            return None
        results = read_results(base / path, f"<!-- benchmark {path} -->")
        return markdown(results, path) + "\n"

    new, n = regenerate(text, "benchmark", "benchmark", render)
    if not n:
        raise typer.BadParameter(
            "no '<!-- benchmark PATH -->' ... '<!-- end of benchmark -->' block found",
            param_hint="--update",
        )
    if only is not None and all((base / p).resolve() != only.resolve() for p in named):
        raise typer.BadParameter(
            f"no block names {only} (its blocks name: {', '.join(named)}, relative to {base})",
            param_hint="--report",
        )
    return new
