"""Seeded lock-step episodes for end-to-end tests, run in parallel by the bench's own trial
runner (one server + planner pair per core, one rollout thread each).

A lock-step episode repeats exactly for a seed on one machine, but not across machines: other
CPUs round differently, and contact-rich episodes amplify the difference. So end-to-end tests
run a few seeds and assert rates with a stated margin, or properties that do not depend on
the chaotic details (which actions active inference chooses after a disturbance, the modes
used, never touching an obstacle).
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from m3p2i import bench as B
from server.evaluation import log_reader
from server.evaluation.metrics import MetricsEvaluator
from shared.scenario import find_scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Episode:
    """One finished episode: its bench row, its log and the planner's output."""

    row: dict
    records: list[dict]
    planner_log: str

    @property
    def summary(self) -> dict:
        return log_reader.summary(self.records) or {}

    @property
    def success(self) -> bool:
        return bool(self.row["success"])

    @property
    def steps(self) -> list[dict]:
        return log_reader.steps(self.records)

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


Spec = tuple[str, "str | Path", int]  # (label, scenario name or file, seed)


def run_episodes(
    specs: list[Spec], out: Path, workers: int = 2, timeout: float = 600.0
) -> dict[tuple[str, int], Episode]:
    """Run ``(label, scenario, seed)`` episodes, ``workers`` at a time, in the order given;
    keyed by (label, seed). A trial the harness had to kill (time-out, crash) fails the test
    with its reason."""
    _run_trials(specs, out, workers, timeout)
    return load_episodes(specs, out)


def _run_trials(specs: list[Spec], out: Path, workers: int, timeout: float) -> None:
    trials = []
    for label, scenario, seed in specs:
        sc = load_scenario(scenario)
        trials.append(
            B.Trial(B.BenchCase(label, "", str(scenario), 1), sc, MetricsEvaluator(sc), seed)
        )
    opts = B.BenchOptions(out_dir=out, workers=workers, timeout=timeout)
    results = B.ResultsFile(out / "results.csv")
    assert B.run_trials(trials, opts, results), "interrupted"


def load_episodes(specs: list[Spec], out: Path) -> dict[tuple[str, int], Episode]:
    """The finished episodes of ``specs`` that a run wrote to ``out``, keyed by (label, seed)."""
    done = {}
    for row in B.ResultsFile(out / "results.csv").rows():
        assert not row["reason"], f"{row['case']} seed {row['seed']}: {row['reason']}"
        row = {**row, "success": row["success"] == "1"}
        log = out / row["log"]
        done[(row["case"], int(row["seed"]))] = Episode(
            row, log_reader.read_log(log), (log.parent / "planner.log").read_text()
        )
    missing = [(label, seed) for label, _, seed in specs if (label, seed) not in done]
    assert not missing, f"no result for {missing}"
    return done


class BackgroundEpisodes:
    """:func:`run_episodes` in a child process at the lowest CPU priority (``nice`` 19, which
    its servers and planners inherit), started when the session starts: the episodes use the
    cores the other tests leave idle (waiting for subprocesses, sockets, sleeps, a browser)
    instead of adding their own minutes to the suite, and take almost nothing from a test that
    needs the CPU. Lock-step episodes do not depend on the load, so their results are those of
    a run on idle cores. :meth:`result` waits for them, first raising the child back to normal
    priority where permitted (only root may), since nothing else is left to give way to."""

    def __init__(self, specs: list[Spec], out: Path, workers: int = 2, timeout: float = 1800.0):
        self.specs, self.out = specs, out
        (out / "specs.json").write_text(json.dumps([[label, str(sc), s] for label, sc, s in specs]))
        self._log = (out / "pool.log").open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.episodes", str(out), str(workers), str(timeout)],
            cwd=ROOT,
            env={
                **os.environ,
                "PYTHONPATH": os.pathsep.join(
                    filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])
                ),
            },
            stdout=self._log,
            stderr=subprocess.STDOUT,
            preexec_fn=_niced_child,
        )

    def result(self) -> dict[tuple[str, int], Episode]:
        _renice_tree(self.proc.pid, 0)
        code = self.proc.wait()
        self._log.close()
        tail = (self.out / "pool.log").read_text()[-4000:]
        assert code == 0, f"the episodes' pool exited with {code}:\n{tail}"
        return load_episodes(self.specs, self.out)

    def stop(self) -> None:
        """Interrupt a pool still running (the session ended first: -x, Ctrl-C): the bench
        stops its trials' processes on SIGINT, as on Ctrl-C."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


_PR_SET_PDEATHSIG = 1  # prctl(2)


def _niced_child() -> None:
    os.nice(19)
    # Ctrl-C semantics even where the suite runs with SIGINT ignored (`pytest &`), and SIGINT
    # when pytest dies without stopping the pool: its trials' processes go with it
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGINT)


def _renice_tree(pid: int, niceness: int) -> None:
    """Set ``niceness`` on every thread of ``pid`` and of its descendants (the pool's servers
    and planners): Linux keeps a niceness per thread, and a thread's children inherit its own."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(stat.parent.name))
    todo = [pid]
    while todo:
        p = todo.pop()
        todo += children.get(p, [])
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                os.setpriority(os.PRIO_PROCESS, int(task.name), niceness)
            except (PermissionError, ProcessLookupError):
                pass  # not root: the pool keeps its low priority, and still gets idle cores


def main() -> None:
    """The child of :class:`BackgroundEpisodes`: ``python -m tests.episodes OUT WORKERS
    TIMEOUT`` runs the episodes listed in ``OUT/specs.json`` into ``OUT``."""
    out, workers, timeout = Path(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    specs = [
        (label, sc, int(seed)) for label, sc, seed in json.loads((out / "specs.json").read_text())
    ]
    _run_trials(specs, out, workers, timeout)


if __name__ == "__main__":
    main()
