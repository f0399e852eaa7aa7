"""``m3p2i tune``: a scenario's parameters found by a search over bench trials (thesis Sec. 6.3:
"an algorithm that can automatically tune these hyperparameters"), not by hand.

A **space file** (``configs/tune/*.yaml``, docs/tune.md) names scenario keys and their ranges or
choices, and the objective's weights. Every value of the space is read by the scenario loader
before any trial (the loader's message for a misspelt key or a value out of its range), and the
space's two corners (every key at its low end, every key at its high end) by both processes'
``--check``. Optuna's TPE proposes a parameter set per study trial; the bench runs it on the
training seeds (warm process pairs, or Ray tasks) and appends its rows to ``results.csv``; the
objective scores them. Trial 0 is the original's values when the scenario sets every key inside
the space, so a study never reports a set worse on its own seeds than what it started from.

Deterministic for its seed: the sampler of the study's n-th finished trial is seeded from
(``--sampler-seed``, n) and lock-step episodes repeat on one machine, so two studies with the
same seed propose the same sets. Resumable: the study lives in ``OUT/study.db`` (SQLite); a rerun
marks an interrupted trial failed, proposes it again (the same set, from the same seed and
history) and reuses the seeds it had finished (``results.csv`` keeps them by scenario hash).

The best set is written as ``OUT/overlay.yaml`` (``base:`` the original plus the tuned keys) and
evaluated beside the original on held-out seeds; ``OUT/report.md`` has the history, the
parameter importances, the best trial's seeds and that evaluation with Wilson intervals.

Modules: ``space`` (the space file), ``target`` (what is tuned), ``study`` (the Optuna study),
``holdout``, ``report``, ``run`` (the command end to end)."""

from m3p2i.tune.holdout import holdout, parse_seeds
from m3p2i.tune.report import report
from m3p2i.tune.run import run_tune
from m3p2i.tune.space import load_space
from m3p2i.tune.study import Events, TuneOptions, best_values, run_study
from m3p2i.tune.target import check_space, resolve_target, values_id, write_overlay
