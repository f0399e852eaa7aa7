"""The speed table of docs/speed.md: ``python scripts/benchmark.py --report FILE --update
docs/speed.md`` regenerates its ``<!-- benchmark PATH -->`` blocks from the results files that
``scripts/benchmark.py --out`` writes (median and range over the runs), so the table is never
typed by hand."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import typer

from m3p2i.blocks import regenerate


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
    lines += [
        "",
        f"Median (min-max) over {results['runs']} runs of `{results['command']}`, "
        f"{results['date']}, {results['machine']}"
        + (f" ({results['versions']})" if results.get("versions") else "")
        + f", {results['threads']} rollout threads, "
        f"median of {results['iterations']} iterations per run; from `{source}`.",
    ]
    return "\n".join(lines)


def update(text: str, base: Path) -> str:
    """``text`` with every ``<!-- benchmark PATH -->`` block regenerated from its results file
    (PATH relative to ``base``)."""
    new, n = regenerate(
        text,
        "benchmark",
        "benchmark",
        lambda path: markdown(json.loads((base / path).read_text()), path) + "\n",
    )
    if not n:
        raise typer.BadParameter(
            "no '<!-- benchmark PATH -->' ... '<!-- end of benchmark -->' block found",
            param_hint="--update",
        )
    return new
