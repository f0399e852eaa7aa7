"""OUT/report.md: the space, the trials, the parameter importances and the held-out comparison."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from m3p2i import bench as B
from m3p2i.bench_report import seed_ranges, wilson
from m3p2i.provenance import machine, versions
from m3p2i.tune.holdout import Held
from m3p2i.tune.space import Space
from m3p2i.tune.study import (
    Score,
    TuneOptions,
    best_values,
    cell_number,
    finished_trials,
    trial_score,
)
from m3p2i.tune.target import Target, run_options


def cell_text(v: Any) -> str:
    """A value as a table cell: a string as it is, anything else as JSON."""
    return json.dumps(v) if not isinstance(v, str) else v


def importances(study) -> dict[str, float] | str:
    """Optuna's parameter importances over the complete trials (pruned ones are not used), or
    why there are none."""
    import optuna
    from optuna.trial import TrialState

    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len({json.dumps(t.params, sort_keys=True) for t in complete}) < 2:
        # the evaluator would share the importance out evenly: a number that says nothing
        return f"{len(complete)} complete trial(s) of distinct values; it needs 2 or more"
    try:
        return optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError, ImportError) as exc:
        return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


@dataclass(frozen=True)
class _Sources:
    """What the report is written from: the study, its episodes in ``results.csv``, its best
    trial and the overlay written for it."""

    target: Target
    space: Space
    opts: TuneOptions
    study: Any  # optuna.Study
    rows: list[dict]
    best: Any  # the best complete optuna FrozenTrial
    overlay_path: Path

    def score(self, trial) -> Score:
        """The trial's latest episode on each training seed."""
        return trial_score(trial, self.target, self.rows, self.opts.seeds)


def report(
    target: Target,
    space: Space,
    opts: TuneOptions,
    study,
    overlay_path: Path,
    held: Held | None,
) -> str:
    """``report.md``: the study's history, importances, best trial per seed, held-out
    comparison."""
    best, _ = best_values(study)
    rows = B.ResultsFile(opts.out / "results.csv").rows()
    src = _Sources(target, space, opts, study, rows, best, overlay_path)
    lines = [
        *_summary(src),
        *_trials_table(src),
        *_importances_section(study),
        *_best_per_seed(src),
        *_held_out_section(src, held),
    ]
    return "\n".join(lines) + "\n"


def _summary(src: _Sources) -> list[str]:
    """The title and what was tuned, how, on which seeds and machine, and the best trial."""
    opts, space, overlay_path = src.opts, src.space, src.overlay_path
    wall = sum(cell_number(r.get("trial_wall")) or 0.0 for r in src.rows)
    return [
        f"# m3p2i tune: {src.target.scenario.name}",
        "",
        f"- target: {src.target.label}",
        f"- space: `{space.source}`: "
        + "; ".join(f"`{p.key}` {p.describe()}" for p in space.params),
        f"- objective (maximised): {space.objective.formula()}",
        f"- training seeds {seed_ranges(opts.seeds)}, held-out seeds "
        f"{seed_ranges(opts.holdout) if opts.holdout else 'none'}; TPE seed {opts.sampler_seed}, "
        f"{space.startup(opts.trials)} random proposals first; pruning "
        f"{'on' if space.prune else 'off'}",
        f"- {len(finished_trials(src.study))} trials finished; episodes' wall time {wall:.0f} s "
        f"(sum over {len(src.rows)} episodes in `results.csv`, on {machine()}, {versions()})",
        f"- best: trial {src.best.number}; overlay `{overlay_path}` "
        f"(`m3p2i run {overlay_path}{run_options(src.target.case)}`)",
        "",
    ]


def _trials_table(src: _Sources) -> list[str]:
    """A row per trial that was proposed (waiting ones are not), the best marked."""
    from optuna.trial import TrialState

    keys = [p.key for p in src.space.params]
    proposed = [t for t in src.study.get_trials(deepcopy=False) if t.state != TrialState.WAITING]
    return [
        "## Trials",
        "",
        "| trial | state | " + " | ".join(f"`{k}`" for k in keys) + " | success | time [s] | "
        "objective |",
        "|---:|---|" + "---:|" * len(keys) + "---:|---:|---:|",
        *(_trial_row(src, t, keys) for t in proposed),
        "",
        "A pruned trial stopped once it could no longer beat the best complete one, even with "
        "every seed left succeeding; its objective is over the seeds it ran. Failed: "
        "interrupted, proposed again.",
        "",
    ]


def _trial_row(src: _Sources, trial, keys: list[str]) -> str:
    vals = trial.user_attrs.get("values", {})
    state = trial.state.name.lower() + (" (original)" if trial.user_attrs.get("original") else "")
    ran = trial.user_attrs.get("seeds_run")
    succ = f"{trial.user_attrs['successes']}/{ran}" if ran else "—"
    objective = _last_objective(trial)
    tstats = src.score(trial).time_stats() if ran else None
    return (
        f"| {trial.number}{' **best**' if trial.number == src.best.number else ''} | {state} | "
        + " | ".join(cell_text(vals.get(k, "—")) for k in keys)
        + f" | {succ} | {f'{tstats[0]:.2f}' if tstats else '—'} | "
        + (f"{objective:.4f}" if objective is not None else "—")
        + " |"
    )


def _last_objective(trial) -> float | None:
    """A trial's objective; a pruned trial has none of its own, but reported one at its last
    step (over the seeds it ran)."""
    if trial.value is not None:
        return trial.value
    if trial.intermediate_values:
        return trial.intermediate_values[max(trial.intermediate_values)]
    return None


def _importances_section(study) -> list[str]:
    """Optuna's importance of each key, or why it is not computable."""
    lines = ["## Parameter importances", ""]
    imp = importances(study)
    if isinstance(imp, str):
        return [*lines, f"Not computable: {imp}"]
    return [
        *lines,
        "| key | importance |",
        "|---|---:|",
        *(f"| `{k}` | {v:.3f} |" for k, v in imp.items()),
        "",
        "Optuna's default evaluator over the complete trials; few trials, rough.",
    ]


def _best_per_seed(src: _Sources) -> list[str]:
    """The best trial's episode on each training seed, with its log."""
    return [
        "",
        f"## Best trial ({src.best.number}) per seed",
        "",
        "| seed | status | reason | time [s] | position error [m] | collisions | log |",
        "|---:|---|---|---:|---:|---:|---|",
        *(
            f"| {r['seed']} | {r['status']} | {r.get('reason') or ''} | {_fmt(r.get('time'))} | "
            f"{_fmt(r.get('position_error'), 3)} | {r.get('collisions') or '—'} | "
            f"`{r.get('log', '')}` |"
            for r in src.score(src.best).rows
        ),
    ]


def _held_out_section(src: _Sources, held: Held | None) -> list[str]:
    """The original against the tuned overlay on the held-out seeds, or why there is none."""
    lines = ["", "## Held-out evaluation", ""]
    if held is None:
        return [
            *lines,
            "No held-out seeds (--holdout): the tuned set is judged on its own seeds only.",
        ]
    ran = sorted(int(r["seed"]) for r in held.original.rows)
    left = seed_ranges(sorted(set(src.opts.holdout) - set(ran)))
    sides = zip(
        (f"original ({src.target.base})", f"tuned (`{src.overlay_path}`)"),
        (held.original, held.tuned),
    )
    return [
        *lines,
        f"Seeds {seed_ranges(ran) if ran else 'none yet'}, none tuned on; "
        f"{src.target.case.mode_label}."
        + (
            ""
            if held.complete
            else f" Interrupted before seeds {left}: rerun the same command to finish."
        ),
        "",
        "| scenario | success (95 % Wilson interval) | time [s] | position error [m] | "
        "failed seeds | objective |",
        "|---|---:|---:|---:|---|---:|",
        *(_held_out_row(src, name, score) for name, score in sides if score.trials),
        "",
        "time: mean (std) simulated seconds to success over the successful trials.",
    ]


def _held_out_row(src: _Sources, name: str, score: Score) -> str:
    max_time = src.target.scenario.episode.max_time
    lo, hi = wilson(score.successes, score.trials)
    ts = score.time_stats()
    return (
        f"| {name} | {score.successes}/{score.trials} ({100 * lo:.0f}-{100 * hi:.0f} %) | "
        f"{f'{ts[0]:.2f} ({ts[1]:.2f})' if ts else '—'} | "
        f"{score.mean('position_error', max_time):.3f} | "
        f"{', '.join(map(str, score.failed_seeds())) or 'none'} | "
        f"{score.value(src.space.objective, max_time):.4f} |"
    )


def _fmt(cell: Any, digits: int = 2) -> str:
    v = cell_number(cell)
    return f"{v:.{digits}f}" if v is not None else "—"
