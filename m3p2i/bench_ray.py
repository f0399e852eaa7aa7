"""``m3p2i bench --ray`` / ``--ray-address``: the bench's trials as Ray tasks (Ray core API only).

Each trial is one task declaring ``--cpus-per-trial`` CPUs. The task carries the scenario file's
text, writes it into a temporary folder of whichever node runs it, checks that the node reads
it to the same hash as the driver did (same m3p2i, same included objective files), and runs the
bench's own trial function (:func:`m3p2i.bench.run_trial`: a world + planner pair on free
loopback ports of that node). It returns the results row and the trial's log files; the driver
writes both into the output folder exactly as the local pool does, so ``results.csv`` resumes
the same way whichever ran it.

A task that fails (its worker killed, the node lost, an exception) or runs past the trial
time-out plus a grace period (then it is cancelled: first politely, so the trial stops its two
processes, then by force) is recorded as a failure row with the reason; the bench never hangs on
it. Tasks are not retried: a rerun of the bench runs them again, as any unfinished trial.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from m3p2i.bench import BenchCase, BenchOptions, ResultsFile, Trial, run_trial
from m3p2i.provenance import machine, versions
from m3p2i.sweep import to_cell
from server.evaluation.metrics import MetricsEvaluator
from shared.scenario import load_scenario

# seconds a task may run past the trial time-out (start-up of the two processes, scheduling)
GRACE = 60.0
# seconds between a polite cancel (KeyboardInterrupt in the task) and a forced one
FORCE_AFTER = 15.0


class RayUnavailable(RuntimeError):
    """Ray is not installed or the cluster cannot be reached."""


@dataclass(frozen=True)
class Cluster:
    """The Ray instance the bench runs on."""

    address: str | None  # None: a local instance started by the bench
    cpus: float  # CPUs of the whole cluster, as Ray counts them
    nodes: int

    def describe(self) -> str:
        where = f"cluster at {self.address}" if self.address else "local instance"
        return f"{where}, {self.nodes} node(s), {self.cpus:g} CPUs"


def connect(address: str | None, cpus: int) -> Cluster:
    """Join the Ray cluster at ``address``, or start a local instance of ``cpus`` CPUs; an
    instance this process already started (``ray.init`` in a test) is used as it is."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no network at run time
    # a local instance: a worker that dies (killed, cancelled by force) takes its process group
    # with it, i.e. the trial's world and planner, instead of leaving them running
    os.environ.setdefault("RAY_process_group_cleanup_enabled", "1")
    try:
        import ray
    except ImportError:
        raise RayUnavailable("--ray needs Ray: pip install 'm3p2i[cluster]'") from None
    if not ray.is_initialized():
        try:
            if address:
                ray.init(address=address, log_to_driver=False)
            else:
                ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise RayUnavailable(
                f"cannot start or reach Ray{f' at {address}' if address else ''}: {exc}"
            ) from None
    alive = [n for n in ray.nodes() if n.get("Alive")]
    return Cluster(address, float(ray.cluster_resources().get("CPU", 0.0)), len(alive))


@dataclass(frozen=True)
class TrialTask:
    """What a Ray task needs to run one trial: plain data, the scenario as text."""

    case: BenchCase
    scenario_file: str  # file name; its stem is the scenario's default name
    scenario_text: str
    scenario_hash: str  # as the driver read it
    seed: int
    overrides: dict
    timeout: float
    threads: int


def task_of(trial: Trial, opts: BenchOptions, threads: int) -> TrialTask:
    """The task of ``trial``: the scenario file's text travels with it."""
    path = Path(trial.scenario.source)
    return TrialTask(
        trial.case,
        path.name,
        path.read_text(),
        trial.scenario.hash,
        trial.seed,
        dict(trial.overrides),
        opts.timeout,
        threads,
    )


def remote_trial(task: TrialTask) -> tuple[dict, dict[str, bytes]]:
    """Run one trial on this node (the body of the Ray task): its row and its log files
    (paths relative to the bench's output folder -> content)."""
    work = Path(tempfile.mkdtemp(prefix="m3p2i-trial-"))
    try:
        path = work / "scenario" / task.scenario_file
        path.parent.mkdir()
        path.write_text(task.scenario_text)
        scenario = load_scenario(path)
        trial = Trial(task.case, scenario, MetricsEvaluator(scenario), task.seed, task.overrides)
        if scenario.plugins:
            # the planner imports a scenario's plugins: never the ones a text received names
            return failure_row(
                trial,
                f"the scenario names plugins ({', '.join(scenario.plugins)}): a node imports "
                "no module that a scenario sent to it names; run it on the driver's pool",
            ), {}
        if scenario.hash != task.scenario_hash:
            # another m3p2i version or other included objective files on this node
            return failure_row(
                trial,
                f"the scenario reads differently on this node (hash "
                f"{scenario.hash}, driver {task.scenario_hash})",
            ), {}
        opts = BenchOptions(out_dir=work, workers=1, timeout=task.timeout)
        row = run_trial(trial, opts, task.threads, threading.Event())
        if row is None:  # only a cancel interrupts it
            return failure_row(trial, "the Ray task was cancelled"), {}
        row["scenario_hash"] = task.scenario_hash
        files = {
            str(p.relative_to(work)): p.read_bytes()
            for p in sorted((work / trial.log_dir).rglob("*"))
            if p.is_file()
        }
        return row, files
    finally:
        shutil.rmtree(work, ignore_errors=True)


def failure_row(trial: Trial, reason: str) -> dict:
    """The results row of a trial that produced no episode of its own."""
    return {
        "case": trial.case.case,
        "variant": trial.case.variant,
        "scenario": trial.scenario.name,
        "scenario_hash": trial.scenario.hash,
        "seed": trial.seed,
        "success": False,
        "status": "failure",
        "reason": reason,
        "machine": machine(),
        "versions": versions(),
        "date": time.strftime("%Y-%m-%d"),
        "mode": trial.case.mode_label,
        "overrides": to_cell(trial.overrides),
    }


def run_trials(
    todo: list[Trial],
    opts: BenchOptions,
    results: ResultsFile,
    cluster: Cluster,
    cpus_per_trial: int,
    on_done: Callable[[dict], None] = lambda row: None,
) -> bool:
    """Run ``todo`` as Ray tasks; rows and logs are written as tasks finish. Like the local
    pool, real-time trials come last and one at a time. False when interrupted (Ctrl-C):
    running tasks are cancelled and left out of the file."""
    waiting = [t for t in todo if t.case.mode != "realtime"]
    realtime = [t for t in todo if t.case.mode == "realtime"]
    capacity = max(1, int(cluster.cpus // cpus_per_trial))
    return _run(waiting, capacity, opts, results, cpus_per_trial, on_done) and _run(
        realtime, 1, opts, results, cpus_per_trial, on_done
    )


def _run(
    todo: list[Trial],
    capacity: int,
    opts: BenchOptions,
    results: ResultsFile,
    cpus: int,
    on_done: Callable[[dict], None],
) -> bool:
    import ray
    from ray.exceptions import RayError, TaskCancelledError

    # no retries: a trial whose worker died is a failure row, rerun by resuming the bench
    remote = ray.remote(remote_trial).options(num_cpus=cpus, max_retries=0)
    queue = list(todo)
    running: dict = {}  # ref -> (trial, submitted at)
    cancelled: dict = {}  # ref -> (reason, cancelled at, forced)
    try:
        while queue or running:
            # no more tasks than fit at once: a task's clock starts when it can start
            while queue and len(running) < capacity:
                trial = queue.pop(0)
                ref = remote.remote(task_of(trial, opts, cpus))
                running[ref] = (trial, time.monotonic())
            ready, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for ref in ready:
                trial, _ = running.pop(ref)
                files: dict[str, bytes] = {}
                try:
                    row, files = ray.get(ref)
                except TaskCancelledError:
                    row = failure_row(trial, cancelled.get(ref, ("the Ray task was cancelled",))[0])
                except RayError as exc:
                    row = failure_row(trial, f"the Ray task failed: {_first_line(exc)}")
                if ref in cancelled:  # it may have stopped its trial and returned
                    row, files = failure_row(trial, cancelled[ref][0]), {}
                _write_logs(opts.out_dir, trial, files)
                results.append(row)
                on_done(row)
                cancelled.pop(ref, None)
            now = time.monotonic()
            for ref, (_trial, started) in running.items():
                if ref not in cancelled and now - started > opts.timeout + GRACE:
                    ray.cancel(ref)  # KeyboardInterrupt: the trial stops its processes
                    cancelled[ref] = (
                        f"timeout: the Ray task ran past {opts.timeout:.0f} s + "
                        f"{GRACE:.0f} s and was cancelled",
                        now,
                        False,
                    )
                elif (
                    ref in cancelled
                    and not cancelled[ref][2]
                    and now - cancelled[ref][1] > FORCE_AFTER
                ):
                    ray.cancel(ref, force=True)
                    cancelled[ref] = (cancelled[ref][0], now, True)
    except BaseException as exc:  # Ctrl-C, or on_done stopping the run (m3p2i tune's pruning)
        for ref in running:
            ray.cancel(ref, force=True)
        if isinstance(exc, KeyboardInterrupt):
            return False
        raise
    return True


def _write_logs(out_dir: Path, trial: Trial, files: dict[str, bytes]) -> None:
    """The trial's log files where the local pool would have written them; a stale log of an
    earlier attempt is removed first, as the local pool does."""
    shutil.rmtree(out_dir / trial.log_dir, ignore_errors=True)
    for rel, data in files.items():
        path = out_dir / rel
        if not path.resolve().is_relative_to((out_dir / trial.log_dir).resolve()):
            continue  # only the trial's own folder
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".strip()
