"""The best set against the original on held-out seeds."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

from m3p2i import bench as B
from m3p2i.tune.study import Events, Runner, Score, TuneOptions
from m3p2i.tune.target import Target
from server.evaluation.metrics import MetricsEvaluator
from shared.config import ConfigError
from shared.protocol import MAX_SEED
from shared.scenario import load_scenario

MAX_SEEDS = 10_000  # episodes per trial: a typo like 0-9999999 must not start a study


@dataclass(frozen=True)
class Held:
    """The held-out comparison: the original's and the tuned overlay's scores on the same
    seeds; ``complete``: every held-out seed ran for both (False: interrupted, a rerun
    finishes it)."""

    original: Score
    tuned: Score
    complete: bool


def holdout(
    target: Target, overlay_path: Path, opts: TuneOptions, runner: Runner, events: Events
) -> Held:
    """The original and the tuned overlay on the held-out seeds, both on a seed (``workers``
    seeds at once) before the next, so that an interrupted comparison is still one on the same
    seeds."""
    tuned = load_scenario(overlay_path)
    sides = [
        (target.case, target.scenario),
        (dataclasses.replace(target.case, case=f"{target.case.case}_tuned"), tuned),
    ]
    results = B.ResultsFile(opts.out / "results.csv")
    keys = [{B.trial_key(c.case, s, sc.hash) for s in opts.holdout} for c, sc in sides]
    have = [{int(r["seed"]) for r in B.latest_rows(results.rows(), k)} for k in keys]
    for k in keys:
        for r in B.latest_rows(results.rows(), k):
            events.row(r)
    evaluators = [MetricsEvaluator(sc) for _, sc in sides]
    todo = [
        [
            B.Trial(c, sc, ev, s)
            for (c, sc), ev, done in zip(sides, evaluators, have)
            if s not in done
        ]
        for s in opts.holdout
    ]
    todo = [t for t in todo if t]
    complete = True
    for i in range(0, len(todo), max(1, opts.workers)):
        chunk = [t for seed in todo[i : i + max(1, opts.workers)] for t in seed]
        if not runner(chunk, results, events.row):
            complete = False
            break
    rows = results.rows()
    scores = [
        Score(tuple(sorted(B.latest_rows(rows, k), key=lambda r: int(r["seed"])))) for k in keys
    ]
    common = {int(r["seed"]) for r in scores[0].rows} & {int(r["seed"]) for r in scores[1].rows}
    original, tuned_score = (
        Score(tuple(r for r in sc.rows if int(r["seed"]) in common)) for sc in scores
    )
    return Held(original, tuned_score, complete and len(common) == len(opts.holdout))


def write_holdout(held: Held, path: Path) -> None:
    """``holdout.csv``: the held-out rows alone, the original's then the tuned overlay's, in
    the bench's format, so that ``m3p2i report`` tabulates the comparison (docs/tune.md's
    table is such a block). Written whole and then moved into place: never half a file."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    rows = B.ResultsFile(tmp)
    for r in (*held.original.rows, *held.tuned.rows):
        rows.append(r)
    tmp.replace(path)


def parse_seeds(text: str, option: str) -> tuple[int, ...]:
    """``0-9``, ``3``, ``0-4,10,12-13`` -> the seeds in order, each once (at most
    :data:`MAX_SEEDS` of them, none above the protocol's :data:`~shared.protocol.MAX_SEED`)."""
    seeds: dict[int, None] = {}  # ordered, each once
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        lo = int(m.group(1)) if m else 0
        hi = int(m.group(2)) if m and m.group(2) else lo
        if not m or hi < lo or hi > MAX_SEED or len(seeds) + hi - lo >= MAX_SEEDS:
            raise ConfigError(
                option,
                "",
                "not a seed range",
                text,
                f"A-B (A <= B <= {MAX_SEED}), a seed, or a comma list of at most "
                f"{MAX_SEEDS:,} seeds, e.g. 0-9",
            )
        seeds.update(dict.fromkeys(range(lo, hi + 1)))
    return tuple(seeds)
