"""Seeded lock-step episodes for end-to-end tests, run in parallel by the bench's own trial
runner (one server + planner pair per core, one rollout thread each).

A lock-step episode repeats exactly for a seed on one machine, but not across machines: other
CPUs round differently, and contact-rich episodes amplify the difference. So end-to-end tests
run a few seeds and assert rates with a stated margin, or properties that do not depend on
the chaotic details (which actions active inference chooses after a disturbance, the modes
used, never touching an obstacle).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from shared.evaluation import episode
from shared.evaluation.metrics import MetricsEvaluator
from shared.scenario import find_scenario, load_scenario
from shared.tools import bench as B


@dataclass
class Episode:
    """One finished episode: its bench row, its log and the planner's output."""

    row: dict
    records: list[dict]
    planner_log: str

    @property
    def summary(self) -> dict:
        return episode.summary(self.records) or {}

    @property
    def success(self) -> bool:
        return bool(self.row["success"])

    @property
    def steps(self) -> list[dict]:
        return episode.steps(self.records)

    @property
    def actions(self) -> list[str]:
        return [r["action"] for r in self.records if r.get("what") == "action"]

    @property
    def disturbances(self) -> list[dict]:
        return [r for r in self.records if r.get("what") == "disturbance"]


def with_max_time(scenario: str, max_time: float, folder: Path) -> Path:
    """A copy of ``scenario`` in ``folder`` whose episodes end after ``max_time`` simulated s."""
    raw = yaml.safe_load(find_scenario(scenario).read_text())
    raw["episode"]["max_time"] = max_time
    path = folder / f"{raw['name']}-max{max_time:g}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def run_episodes(
    specs: list[tuple[str, str | Path, int]], out: Path, workers: int = 2, timeout: float = 600.0
) -> dict[tuple[str, int], Episode]:
    """Run ``(label, scenario, seed)`` episodes, ``workers`` at a time, in the order given;
    keyed by (label, seed). A trial the harness had to kill (time-out, crash) fails the test
    with its reason."""
    trials = []
    for label, scenario, seed in specs:
        sc = load_scenario(scenario)
        trials.append(
            B.Trial(B.BenchCase(label, "", str(scenario), 1), sc, MetricsEvaluator(sc), seed)
        )
    opts = B.BenchOptions(out_dir=out, workers=workers, timeout=timeout)
    results = B.ResultsFile(out / "results.csv")
    assert B.run_trials(trials, opts, results), "interrupted"
    done = {}
    for row in results.rows():
        assert not row["reason"], f"{row['case']} seed {row['seed']}: {row['reason']}"
        row = {**row, "success": row["success"] == "1"}
        log = out / row["log"]
        done[(row["case"], int(row["seed"]))] = Episode(
            row, episode.read_log(log), (log.parent / "planner.log").read_text()
        )
    missing = [(label, seed) for label, _, seed in specs if (label, seed) not in done]
    assert not missing, f"no result for {missing}"
    return done
