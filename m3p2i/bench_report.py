"""The bench's summary: one row per case, mean (std) like the paper, next to the published
figures of ``configs/paper_results.yaml``; printed with rich and written as Markdown.

Statistics (population std, as the paper's: 3 collisions in 60 trials give 0.0500 (0.2179)):
success over all trials; position/orientation error and collisions over the trials that ended by
themselves (not killed at the time-out, where the final state is arbitrary); completion time over
the successful trials only (the others all last ``max_time``). A table whose cases have perceived
objects adds their contacts and closest approach, over the trials that ended by themselves.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.table import Table

from m3p2i.blocks import regenerate
from shared.config import ConfigError, Section, load_yaml, positive_int, vector
from shared.config_files import shipped

PAPER_RESULTS = shipped("paper_results.yaml")
TIME_OUT = "time-out"
METRICS = ("position_error", "orientation_error", "collisions", "time")
# of a scenario with perceived objects only (server.evaluation.clearance); no paper figures
PERCEIVED = ("perceived_contacts", "perceived_clearance_min")


@dataclass(frozen=True)
class Stat:
    mean: float
    std: float
    n: int
    low: float = math.nan  # the smallest value

    def __str__(self) -> str:
        return f"{self.mean:.4f} ({self.std:.4f})"


@dataclass(frozen=True)
class PaperRow:
    table: str
    row: str
    trials: int
    values: dict[str, tuple[float, float] | str]  # metric -> (mean, std) or "time-out"

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
    values = {
        m: s.req(m, _paper_value, f"[mean, std] or {TIME_OUT!r}") for m in METRICS if s.has(m)
    }
    row = PaperRow(
        table=s.req("table", str),
        row=s.req("row", str),
        trials=s.req("trials", positive_int),
        values=values,
    )
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


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a success rate (95 % for z = 1.96): unlike p ± z·√(p(1-p)/n) it
    stays inside [0, 1] and is not empty at 0/n or n/n, where a bench's rates usually are."""
    if trials <= 0:
        raise ValueError(f"a rate needs at least one trial (got {trials})")
    p = successes / trials
    zz = z * z / trials
    centre = (p + zz / 2) / (1 + zz)
    half = z / (1 + zz) * math.sqrt(p * (1 - p) / trials + zz / (4 * trials))
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass(frozen=True)
class CaseSummary:
    case: str
    variant: str
    trials: int
    successes: int
    killed: int  # trials cut by the harness (time-out, crash)
    stats: dict[str, Stat | None]  # METRICS + planner_hz
    seeds: str = ""  # e.g. "0-49"

    @property
    def success_cell(self) -> str:
        lo, hi = wilson(self.successes, self.trials)
        text = f"{self.successes}/{self.trials} ({100 * lo:.1f}-{100 * hi:.1f} %)"
        return f"{text}, {self.killed} killed" if self.killed else text


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
    return Stat(float(np.mean(vals)), float(np.std(vals)), len(vals), float(np.min(vals)))


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
        for m in PERCEIVED:  # rows written before the columns have none
            stats[m] = _stat([_number(r.get(m)) for r in ended])
        out.append(
            CaseSummary(
                case=case,
                variant=mine[0]["variant"],
                trials=len(mine),
                successes=len(won),
                killed=len(mine) - len(ended),
                stats=stats,
                seeds=seed_ranges(int(r["seed"]) for r in mine),
            )
        )
    return out


def seed_ranges(seeds) -> str:
    """``0-49, 1000-1009``: the seeds as runs of consecutive numbers."""
    runs: list[list[int]] = []
    for seed in sorted(set(seeds)):
        if runs and seed == runs[-1][1] + 1:
            runs[-1][1] = seed
        else:
            runs.append([seed, seed])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


# ------------------------------------------------------------------------------------ rendering

HEADERS = (
    "case",
    "variant",
    "seeds",
    "success (95 % interval)",
    "pos error [m]",
    "paper",
    "ori error (paper Eq. 33)",
    "paper",
    "collisions",
    "paper",
    "time [s]",
    "paper",
    "planner Hz",
)


PERCEIVED_HEADERS = ("perceived contacts", "perceived clearance [m]")

_LEFT = ("case", "variant", "seeds")


def table_rows(
    summaries: list[CaseSummary], paper: dict[str, PaperRow], perceived: bool | None = None
) -> list[list[str]]:
    """One row of :data:`HEADERS` per case; with ``perceived`` (default: when any case
    measured them) each followed by :data:`PERCEIVED_HEADERS`' cells."""
    if perceived is None:
        perceived = any(s.stats.get(m) for s in summaries for m in PERCEIVED)
    rows = []
    for s in summaries:
        p = paper.get(s.case)
        cells = [s.case, s.variant, s.seeds, s.success_cell]
        for m in METRICS:
            st = s.stats[m]
            cells.append(str(st) if st else ("time-out" if m == "time" and s.trials else "—"))
            cells.append(p.cell(m) if p else "—")
        hz = s.stats["planner_hz"]
        cells.append(f"{hz.mean:.1f}" if hz else "—")
        if perceived:
            contacts, clear = (s.stats.get(m) for m in PERCEIVED)
            cells.append(str(contacts) if contacts else "—")
            cells.append(f"{clear}, min {clear.low:.4f}" if clear else "—")
        rows.append(cells)
    return rows


def headers(rows: list[list[str]]) -> tuple[str, ...]:
    """The columns of ``rows`` (:func:`table_rows`): the perceived ones where they have them."""
    return HEADERS + (PERCEIVED_HEADERS if rows and len(rows[0]) > len(HEADERS) else ())


def rich_table(rows: list[list[str]], title: str) -> Table:
    table = Table(title=title, header_style="bold")
    for h in headers(rows):
        table.add_column(h, justify="left" if h in _LEFT else "right")
    for r in rows:
        table.add_row(*r)
    return table


def markdown_table(rows: list[list[str]]) -> str:
    columns = headers(rows)
    lines = [
        "| " + " | ".join(columns) + " |",
        "|" + "|".join("---" if h in _LEFT else "---:" for h in columns) + "|",
    ]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


LEGEND = (
    "Success over all trials, with its 95 % Wilson interval; mean (std) over trials "
    "(population std, as the paper): errors and collisions over the trials that ended by "
    "themselves, time over the successful ones (time-out: none succeeded). *paper*: "
    "configs/paper_results.yaml (Tables I-III)."
)
PERCEIVED_LEGEND = (
    " Perceived contacts: contact onsets of the robot (and the free objects) with the objects "
    "only its sensors show; perceived clearance: the smallest signed distance to them in each "
    "trial (MuJoCo's, every step, at most 1 m): mean (std), and the smallest of all."
)


def legend(rows: list[list[str]]) -> str:
    """:data:`LEGEND`, and what the perceived columns mean where ``rows`` have them."""
    return LEGEND + (PERCEIVED_LEGEND if len(headers(rows)) > len(HEADERS) else "")


def markdown_report(rows: list[list[str]], skipped: list[tuple[str, str]], header: str) -> str:
    """``summary.md``: the table, how it was made, and the cases that were skipped."""
    parts = [header, "", markdown_table(rows), "", legend(rows)]
    if skipped:
        parts += ["", "Skipped cases:", ""] + [f"- `{c}`: {why}" for c, why in skipped]
    return "\n".join(parts) + "\n"


# ------------------------------------------------------------- reports from committed results

# beside results.csv: {case: {seed: one sentence, default: one sentence for its other failures}}
NOTES_FILE = "failures.yaml"


@dataclass(frozen=True)
class Results:
    """One bench's results.csv as a report reads it: per case, the rows of the newest scenario
    version (the hash of its last row), the last row per seed; and the failure notes."""

    path: Path
    rows: list[dict[str, str]]
    notes: dict[tuple[str, int | None], str]  # seed None: the case's default note

    @property
    def cases(self) -> list[str]:
        return list(dict.fromkeys(r["case"] for r in self.rows))


def read_results(path: str | Path) -> Results:
    """``results.csv`` (or the bench folder holding it) and its ``failures.yaml``, if any."""
    path = Path(path)
    csv_path = path / "results.csv" if path.is_dir() else path
    if not csv_path.is_file():
        raise ConfigError(
            str(path), "", "no results file", expected="a bench's results.csv or its output folder"
        )
    with csv_path.open(newline="") as f:
        reader = csv.DictReader(f)
        missing = [
            c for c in ("case", "seed", "scenario_hash") if c not in (reader.fieldnames or [])
        ]
        if missing:
            raise ConfigError(
                str(csv_path),
                "",
                f"no {', '.join(missing)} column",
                expected="a bench's results.csv (m3p2i bench writes it)",
            )
        rows = list(reader)
    # a sweep's variants (same case, other overrides) are versions side by side, not in turn
    newest = {(r["case"], r.get("overrides") or ""): r["scenario_hash"] for r in rows}
    latest = {
        (r["case"], r.get("overrides") or "", int(r["seed"])): r
        for r in rows
        if r["scenario_hash"] == newest[(r["case"], r.get("overrides") or "")]
    }
    notes: dict[tuple[str, int | None], str] = {}
    notes_path = csv_path.parent / NOTES_FILE
    if notes_path.is_file():
        top = Section(load_yaml(notes_path), str(notes_path))
        for case in list(top.data):
            for seed, text in top.section(case).data.items():
                if not (isinstance(seed, int) or seed == "default") or not isinstance(text, str):
                    raise ConfigError(
                        str(notes_path),
                        f"{case}.{seed}",
                        "a failure note is `SEED: one sentence` or `default: one sentence`",
                        text,
                    )
                notes[(case, None if seed == "default" else seed)] = text
    return Results(csv_path, list(latest.values()), notes)


def _failure_lines(rows: list[dict[str, str]], notes: dict[tuple[str, int | None], str]):
    """Per case (in the results' order), one line per failure with its own note, then one
    line for its other failures, which share the case's ``default`` note (or none), their
    seeds as ranges."""
    by_case: dict[str, list[dict[str, str]]] = {}
    for r in rows:
        if r["success"] != "1":
            by_case.setdefault(r["case"], []).append(r)
    lines = []
    for case, failed in by_case.items():
        failed.sort(key=lambda r: int(r["seed"]))
        noted = [r for r in failed if (case, int(r["seed"])) in notes]
        lines += [_failure_line([r], notes[(case, int(r["seed"]))]) for r in noted]
        rest = [r for r in failed if (case, int(r["seed"])) not in notes]
        if rest:
            lines.append(_failure_line(rest, notes.get((case, None), "not explained yet")))
    return lines


def _failure_line(group: list[dict[str, str]], note: str) -> str:
    """``- `case` seed 3: timeout at 20.0 s, 0.3 m from the goal. Note.``; for several
    seeds their ranges, each reason with its count, and the range of times and distances."""
    first = group[0]
    if len(group) == 1:
        error = _number(first["position_error"])
        where = f", {error:.3f} m from the goal" if error is not None else ""
        what = f"{first['reason'] or first['status']} at {_number(first['time']) or 0:.1f} s"
        return f"- `{first['case']}` seed {first['seed']}: {what}{where}. {note}"
    reasons = Counter(r["reason"] or r["status"] for r in group)
    what = ", ".join(f"{k} ({n})" if len(reasons) > 1 else k for k, n in reasons.items())
    times = [t for r in group if (t := _number(r["time"])) is not None]
    errors = [e for r in group if (e := _number(r["position_error"])) is not None]
    if times:
        what += f" at {_span(times, '.1f')} s"
    if errors:
        what += f", {_span(errors, '.3f')} m from the goal"
    seeds = seed_ranges(int(r["seed"]) for r in group)
    return f"- `{first['case']}` seeds {seeds} ({len(group)} failures): {what}. {note}"


def _span(values: list[float], fmt: str) -> str:
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return lo if lo == hi else f"{lo}-{hi}"


def results_report(results: list[Results], paper: dict[str, PaperRow]) -> str:
    """The Markdown a README or doc shows for some results files: one table (a row per case and
    file), the machines and dates the trials ran on, and every failure with its note."""
    from m3p2i.sweep import sweep_report, swept_keys

    rows, failures, machines, dates = [], [], set(), set()
    swept = [r for res in results for r in res.rows if swept_keys([r])]
    if swept:  # a sweep: one table per key; its failures are what the rates count
        return sweep_report(swept) + _trials_ran_on(swept)
    summaries = [summarize(res.rows, res.cases) for res in results]
    perceived = any(s.stats.get(m) for part in summaries for s in part for m in PERCEIVED)
    for res, part in zip(results, summaries):
        rows += table_rows(part, paper, perceived)
        failures += _failure_lines(res.rows, res.notes)
        machines |= {_machine(r) for r in res.rows}
        dates |= {r.get("date") or "date not recorded" for r in res.rows}
    parts = [
        markdown_table(rows),
        "",
        legend(rows) + f" Trials ran on {'; '.join(sorted(machines))}, {', '.join(sorted(dates))}.",
    ]
    if failures:
        parts += ["", "Failures:", ""] + failures
    return "\n".join(parts) + "\n"


def _machine(row: dict[str, str]) -> str:
    """Where a trial ran: the machine, and the library versions where the row records them
    (rows written before the column have none)."""
    where = row.get("machine") or "machine not recorded"
    return f"{where} ({row['versions']})" if row.get("versions") else where


def _trials_ran_on(rows: list[dict[str, str]]) -> str:
    machines = sorted({_machine(r) for r in rows})
    dates = sorted({r.get("date") or "date not recorded" for r in rows})
    return f"\nTrials ran on {'; '.join(machines)}, {', '.join(dates)}.\n"


def grid_report(results: list[Results]) -> str:
    """Successes per scenario (rows) and variant (columns), e.g. a robustness bench's scenarios
    under each compensation: ``k/n`` over the newest version of each case, ``—`` where none ran."""
    won: dict[tuple[str, str], int] = {}
    ran: dict[tuple[str, str], int] = {}
    for r in (r for res in results for r in res.rows):
        key = (r["scenario"], r["variant"])
        ran[key] = ran.get(key, 0) + 1
        won[key] = won.get(key, 0) + (r["success"] == "1")
    scenarios = list(dict.fromkeys(s for s, _ in ran))
    variants = list(dict.fromkeys(v for _, v in ran))
    lines = ["| scenario | " + " | ".join(variants) + " |", "|---|" + "---:|" * len(variants)]
    for sc in scenarios:
        cells = [f"{won[(sc, v)]}/{ran[(sc, v)]}" if (sc, v) in ran else "—" for v in variants]
        lines.append(f"| `{sc}` | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def update_reports(text: str, base: Path, paper: dict[str, PaperRow]) -> str:
    """``text`` with every ``<!-- m3p2i report PATH... -->`` block regenerated from the results
    files it names (relative to ``base``), up to its ``<!-- end of report -->``, and every
    ``<!-- m3p2i grid PATH... -->`` block (:func:`grid_report`) up to ``<!-- end of grid -->``."""

    def read(args: str, tag: str) -> list[Results]:
        if not args:
            raise ConfigError(
                str(base), "", f"a {tag} block names no results file", f"<!-- m3p2i {tag} -->"
            )
        return [read_results(base / p) for p in args.split()]

    text = regenerate(
        text, "m3p2i report", "report", lambda args: results_report(read(args, "report"), paper)
    )[0]
    return regenerate(text, "m3p2i grid", "grid", lambda args: grid_report(read(args, "grid")))[0]
