"""OUT/report.md: the space, the trials, the parameter importances and the held-out comparison."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from m3p2i import bench as B
from m3p2i.bench_report import seed_ranges, wilson
from m3p2i.provenance import machine, versions
from m3p2i.tune.holdout import Held
from m3p2i.tune.space import Space
from m3p2i.tune.study import Score, TuneOptions, best_values, cell_number, finished_trials
from m3p2i.tune.target import Target, run_options, values_id


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
    from optuna.trial import TrialState

    keys = [p.key for p in space.params]
    finished = [t for t in study.get_trials(deepcopy=False) if t.state != TrialState.WAITING]
    best, _ = best_values(study)
    rows = B.ResultsFile(opts.out / "results.csv").rows()
    wall = sum(cell_number(r.get("trial_wall")) or 0.0 for r in rows)
    max_time = target.scenario.episode.max_time
    lines = [
        f"# m3p2i tune: {target.scenario.name}",
        "",
        f"- target: {target.label}",
        f"- space: `{space.source}`: "
        + "; ".join(f"`{p.key}` {p.describe()}" for p in space.params),
        f"- objective (maximised): {space.objective.formula()}",
        f"- training seeds {seed_ranges(opts.seeds)}, held-out seeds "
        f"{seed_ranges(opts.holdout) if opts.holdout else 'none'}; TPE seed {opts.sampler_seed}, "
        f"{space.startup(opts.trials)} random proposals first; pruning "
        f"{'on' if space.prune else 'off'}",
        f"- {len(finished_trials(study))} trials finished; episodes' wall time {wall:.0f} s "
        f"(sum over {len(rows)} episodes in `results.csv`, on {machine()}, {versions()})",
        f"- best: trial {best.number}; overlay `{overlay_path}` "
        f"(`m3p2i run {overlay_path}{run_options(target.case)}`)",
        "",
        "## Trials",
        "",
        "| trial | state | " + " | ".join(f"`{k}`" for k in keys) + " | success | time [s] | "
        "objective |",
        "|---:|---|" + "---:|" * len(keys) + "---:|---:|---:|",
    ]
    for t in finished:
        vals = t.user_attrs.get("values", {})
        state = t.state.name.lower() + (" (original)" if t.user_attrs.get("original") else "")
        ran = t.user_attrs.get("seeds_run")
        succ = f"{t.user_attrs['successes']}/{ran}" if ran else "—"
        objective = (
            t.value
            if t.value is not None
            else (
                t.intermediate_values[max(t.intermediate_values)] if t.intermediate_values else None
            )
        )
        tstats = _trial_score(t, target, rows, opts.seeds).time_stats() if ran else None
        lines.append(
            f"| {t.number}{' **best**' if t.number == best.number else ''} | {state} | "
            + " | ".join(cell_text(vals.get(k, "—")) for k in keys)
            + f" | {succ} | {f'{tstats[0]:.2f}' if tstats else '—'} | "
            + (f"{objective:.4f}" if objective is not None else "—")
            + " |"
        )
    lines += [
        "",
        "A pruned trial stopped once it could no longer beat the best complete one, even with "
        "every seed left succeeding; its objective is over the seeds it ran. Failed: "
        "interrupted, proposed again.",
        "",
        "## Parameter importances",
        "",
    ]
    imp = importances(study)
    if isinstance(imp, str):
        lines.append(f"Not computable: {imp}")
    else:
        lines += ["| key | importance |", "|---|---:|"]
        lines += [f"| `{k}` | {v:.3f} |" for k, v in imp.items()]
        lines += ["", "Optuna's default evaluator over the complete trials; few trials, rough."]
    score = _trial_score(best, target, rows, opts.seeds)
    lines += [
        "",
        f"## Best trial ({best.number}) per seed",
        "",
        "| seed | status | reason | time [s] | position error [m] | collisions | log |",
        "|---:|---|---|---:|---:|---:|---|",
    ]
    for r in score.rows:
        lines.append(
            f"| {r['seed']} | {r['status']} | {r.get('reason') or ''} | {_fmt(r.get('time'))} | "
            f"{_fmt(r.get('position_error'), 3)} | {r.get('collisions') or '—'} | "
            f"`{r.get('log', '')}` |"
        )
    lines += ["", "## Held-out evaluation", ""]
    if held is None:
        lines.append(
            "No held-out seeds (--holdout): the tuned set is judged on its own seeds only."
        )
    else:
        ran = sorted(int(r["seed"]) for r in held.original.rows)
        left = seed_ranges(sorted(set(opts.holdout) - set(ran)))
        lines += [
            f"Seeds {seed_ranges(ran) if ran else 'none yet'}, none tuned on; "
            f"{target.case.mode_label}."
            + (
                ""
                if held.complete
                else f" Interrupted before seeds {left}: rerun the same command to finish."
            ),
            "",
            "| scenario | success (95 % Wilson interval) | time [s] | position error [m] | "
            "failed seeds | objective |",
            "|---|---:|---:|---:|---|---:|",
        ]
        for name, s in zip(
            (f"original ({target.base})", f"tuned (`{overlay_path}`)"), (held.original, held.tuned)
        ):
            if not s.trials:
                continue
            lo, hi = wilson(s.successes, s.trials)
            ts = s.time_stats()
            lines.append(
                f"| {name} | {s.successes}/{s.trials} ({100 * lo:.0f}-{100 * hi:.0f} %) | "
                f"{f'{ts[0]:.2f} ({ts[1]:.2f})' if ts else '—'} | "
                f"{s.mean('position_error', max_time):.3f} | "
                f"{', '.join(map(str, s.failed_seeds())) or 'none'} | "
                f"{s.value(space.objective, max_time):.4f} |"
            )
        lines += [
            "",
            "time: mean (std) simulated seconds to success over the successful trials.",
        ]
    return "\n".join(lines) + "\n"


def _trial_score(trial, target: Target, rows: list[dict], seeds: Sequence[int]) -> Score:
    values = trial.user_attrs.get("values", {})
    case = f"{target.case.case}@{values_id(values)}"
    mine = [r for r in rows if r["case"] == case and int(r["seed"]) in seeds]
    latest = {int(r["seed"]): r for r in mine}
    return Score(tuple(latest[s] for s in sorted(latest)))


def _fmt(cell: Any, digits: int = 2) -> str:
    v = cell_number(cell)
    return f"{v:.{digits}f}" if v is not None else "—"
