"""The bench's summary: one row per case, mean (std) like the paper, next to the published
figures of ``configs/paper_results.yaml``; printed with rich and written as Markdown.

Statistics (population std, as the paper's: 3 collisions in 60 trials give 0.0500 (0.2179)):
success over all trials; position/orientation error and collisions over the trials that ended by
themselves (not killed at the time-out, where the final state is arbitrary); completion time over
the successful trials only (the others all last ``max_time``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.table import Table

from shared.config import Section, load_yaml, positive_int, vector
from shared.scenario import PROJECT_ROOT

PAPER_RESULTS = PROJECT_ROOT / "configs" / "paper_results.yaml"
TIME_OUT = "time-out"
METRICS = ("position_error", "orientation_error", "collisions", "time")


@dataclass(frozen=True)
class Stat:
    mean: float
    std: float
    n: int

    def __str__(self) -> str:
        return f"{self.mean:.4f} ({self.std:.4f})"


@dataclass(frozen=True)
class PaperRow:
    table: str
    row: str
    trials: int
    values: dict[str, tuple[float, float] | str]   # metric -> (mean, std) or "time-out"

    def cell(self, metric: str) -> str:
        v = self.values.get(metric)
        if v is None:
            return "—"
        return v if isinstance(v, str) else f"{v[0]:.4f} ({v[1]:.4f})"


def _paper_value(value) -> tuple[float, float] | str:
    if value == TIME_OUT:
        return TIME_OUT
    return vector(2)(value)


def _paper_row(s: Section) -> PaperRow:
    values = {m: s.req(m, _paper_value, f"[mean, std] or {TIME_OUT!r}")
              for m in METRICS if s.has(m)}
    row = PaperRow(table=s.req("table", str), row=s.req("row", str),
                   trials=s.req("trials", positive_int), values=values)
    s.done()
    return row


def load_paper(path: Path = PAPER_RESULTS) -> dict[str, PaperRow]:
    """The published rows keyed by bench case name (baselines are checked, not returned)."""
    top = Section(load_yaml(path), str(path))
    top.req("source", str)
    cases = top.section("cases")
    out = {name: _paper_row(cases.section(name)) for name in cases.data}
    for b in top.items("baselines"):
        _paper_row(b)
    top.done()
    return out


# ---------------------------------------------------------------------------------- statistics

@dataclass(frozen=True)
class CaseSummary:
    case: str
    variant: str
    trials: int
    successes: int
    killed: int                      # trials cut by the harness (time-out, crash)
    stats: dict[str, Stat | None]    # METRICS + planner_hz

    @property
    def success_cell(self) -> str:
        text = f"{self.successes}/{self.trials}"
        return f"{text} ({self.killed} killed)" if self.killed else text


def _number(cell: str) -> float | None:
    try:
        v = float(cell)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _stat(values: list[float | None]) -> Stat | None:
    vals = [v for v in values if v is not None]
    if not vals:
        return None
    return Stat(float(np.mean(vals)), float(np.std(vals)), len(vals))


def summarize(rows: list[dict[str, str]], order: list[str]) -> list[CaseSummary]:
    """Per case (in ``order``), from results.csv rows (strings, as read back)."""
    out = []
    for case in order:
        mine = [r for r in rows if r["case"] == case]
        if not mine:
            continue
        ended = [r for r in mine if not r["reason"]]
        won = [r for r in ended if r["success"] == "1"]
        stats = {m: _stat([_number(r[m]) for r in ended]) for m in METRICS if m != "time"}
        stats["time"] = _stat([_number(r["time"]) for r in won])
        stats["planner_hz"] = _stat([_number(r["planner_hz"]) for r in ended])
        out.append(CaseSummary(case=case, variant=mine[0]["variant"], trials=len(mine),
                               successes=len(won), killed=len(mine) - len(ended), stats=stats))
    return out


# ------------------------------------------------------------------------------------ rendering

HEADERS = ("case", "variant", "trials", "success", "pos error [m]", "paper", "ori error (paper Eq. 33)",
           "paper", "collisions", "paper", "time [s]", "paper", "planner Hz")


def table_rows(summaries: list[CaseSummary], paper: dict[str, PaperRow]) -> list[list[str]]:
    rows = []
    for s in summaries:
        p = paper.get(s.case)
        cells = [s.case, s.variant, str(s.trials), s.success_cell]
        for m in METRICS:
            st = s.stats[m]
            cells.append(str(st) if st else ("time-out" if m == "time" and s.trials else "—"))
            cells.append(p.cell(m) if p else "—")
        hz = s.stats["planner_hz"]
        cells.append(f"{hz.mean:.1f}" if hz else "—")
        rows.append(cells)
    return rows


def rich_table(rows: list[list[str]], title: str) -> Table:
    table = Table(title=title, header_style="bold")
    for h in HEADERS:
        table.add_column(h, justify="left" if h in ("case", "variant") else "right")
    for r in rows:
        table.add_row(*r)
    return table


def markdown_table(rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(HEADERS) + " |",
             "|" + "|".join("---" if h in ("case", "variant") else "---:" for h in HEADERS) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def markdown_report(rows: list[list[str]], skipped: list[tuple[str, str]], header: str) -> str:
    """``summary.md``: the table, how it was made, and the cases that were skipped."""
    parts = [header, "", markdown_table(rows), "",
             "mean (std) over trials (population std, as the paper). Success counts all trials; "
             "errors and collisions the trials that ended by themselves; time the successful ones "
             "(time-out: none succeeded). *paper*: configs/paper_results.yaml (Tables I-III)."]
    if skipped:
        parts += ["", "Skipped cases:", ""] + [f"- `{c}`: {why}" for c, why in skipped]
    return "\n".join(parts) + "\n"

