"""``m3p2i bench``: seeded trials of the paper's cases, in parallel, resumable, with a hard
time-out per trial.

A bench file (``bench/NAME.yaml`` in the user's folders or shipped: :mod:`shared.config_files`)
lists cases ``{case, variant, scenario, trials}``. Trial ``i`` of a case runs one lock-step episode
with seed ``seed + i`` for both the world's randomised start and the planner's sampling, on a
server + planner process pair on its own free ports. Each worker keeps its pair across the trials of
a case, beginning each with a seeded reset (:mod:`m3p2i.warm`: same results as a fresh pair,
without its start-up); ``fresh`` starts two new processes per trial (:mod:`m3p2i.launch`).
Each finished trial appends one row to ``results.csv`` in the output folder (flushed and synced
before the next row), its episode log stays in ``logs/CASE/seed-NNN/``; a rerun skips every (case,
seed) already in the file for the same scenario content (hash), so an interrupted bench resumes
where it stopped. A trial past its time-out is killed and recorded as a failure with reason
``timeout``.
"""

from __future__ import annotations

import csv
import dataclasses
import fnmatch
import json
import os
import queue
import shutil
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from m3p2i.launch import EpisodeLaunch, run_episode
from m3p2i.load import MAX_PROCS, MAX_SECONDS, BusyLoad
from m3p2i.provenance import machine, versions
from m3p2i.sweep import Sweep, apply_overrides, file_label, parse_sweep_section, to_cell
from m3p2i.warm import PairSlot
from server.evaluation import log_reader
from server.evaluation.metrics import MetricsEvaluator
from server.options import MODES, mode_conflicts
from shared.config import (
    ConfigError,
    Section,
    deprecated,
    flag,
    load_yaml,
    one_of,
    positive,
    positive_int,
)
from shared.config_files import find
from shared.scenario import Scenario, find_scenario, load_scenario, parse_scenario
from shared.scenario.faults import read_old_name

# results.csv columns; one row per finished trial
FIELDS = (
    "case",
    "variant",
    "scenario",
    "scenario_hash",
    "seed",
    "success",
    "status",
    "reason",
    "position_error",
    "orientation_error",
    "collisions",
    "perceived_contacts",
    "perceived_clearance_min",
    "time",
    "wall_time",
    "planner_hz",
    "steps",
    "trial_wall",
    "initial",
    "log",
    "machine",
    "versions",
    "date",
    "mode",
    "overrides",
)


@dataclass(frozen=True)
class BenchCase:
    case: str  # unique name; keys the results and configs/paper_results.yaml
    variant: str  # e.g. push / pull / hybrid, normal / reactive
    scenario: str  # scenario name, or a YAML path relative to the bench file
    trials: int
    mode: str = "lockstep"  # lockstep | realtime (run one at a time, on every core)
    plan_every: int = 1  # lockstep: world steps per command (a slow planner, repeatably)
    faults: str = ""  # the world's simulated faults: a profile, or a file's path
    delays: tuple[float, float] | None = None  # compensate: (actuation, state) ms declared
    measure_delays: bool = False  # compensate: measure (the planner measures them online)
    max_rate: float = 0.0  # realtime: the planner's plans per second at most (0: no cap)
    realtime_factor: float = 1.0  # realtime: world seconds per wall second (< 1: a slower world)
    load: int = 0  # busy processes competing for the cores while its trials run (m3p2i.load)

    @property
    def mode_label(self) -> str:
        """As results.csv records it: ``lockstep``, ``realtime``, ``lockstep, plan every 3``,
        with ``, faults lab`` and ``, compensated`` when the case sets them (rows written
        before the rename say ``, hardware lab``)."""
        label = f"lockstep, plan every {self.plan_every}" if self.plan_every > 1 else self.mode
        if self.max_rate:
            label += f", planner at most {self.max_rate:g} Hz"
        if self.realtime_factor != 1.0:
            label += f", world at {self.realtime_factor:g}x wall clock"
        if self.load:
            label += f", {self.load} busy processes"
        if self.faults:
            label += f", faults {Path(self.faults).stem}"
        if self.measure_delays:
            return label + ", delays estimated"
        return label + (", compensated" if self.delays is not None else "")


@dataclass(frozen=True)
class BenchConfig:
    source: str
    cases: tuple[BenchCase, ...]
    timeout: float = 600.0  # wall-clock seconds per trial
    quick_trials: int = 2  # trials per case with --quick
    # every case runs once per combination of these values
    sweep: Sweep = field(default_factory=Sweep)


def _with_faults(case: BenchCase, c: Section, bench: Path) -> BenchCase:
    """A case's ``faults`` (profile, or file relative to the bench file) and ``compensate``
    (``true``: declare its delays to the planner; ``measure``: the planner measures them
    online), checked now, not trial by trial."""
    from server.options import load_faults
    from shared.scenario.faults import PROFILES

    spec = c.opt("faults", "", str, "a profile (nominal, lab, harsh) or a YAML file")
    compensate = c.opt(
        "compensate",
        False,
        _compensation,
        "true (declare the delays), false, or measure (measured online)",
    )
    if spec and spec not in PROFILES:
        if not (bench.parent / spec).is_file():
            raise c.error(
                "faults",
                "neither a profile nor a file",
                spec,
                f"one of: {', '.join(PROFILES)}, or a YAML file of faults: keys "
                f"(relative to the bench file)",
            )
        spec = str((bench.parent / spec).resolve())
    faults = load_faults(spec) if spec else None  # a bad file's error names its own key
    delays = faults.delays if compensate and faults is not None else None
    if compensate and delays is None:
        raise c.error(
            "compensate",
            "no delay to compensate",
            compensate,
            "a case whose faults set actuation_delay_ms or state_delay_ms",
        )
    if compensate == "measure":
        return dataclasses.replace(case, faults=spec, measure_delays=True)
    return dataclasses.replace(case, faults=spec, delays=delays)


def _compensation(value) -> bool | str:
    if value == "estimate":  # the old spelling
        deprecated("compensate: estimate", "write compensate: measure")
        return "measure"
    if value == "measure":
        return value
    return flag(value)


def _busy(value) -> int:
    """A case's ``load``: busy processes, 0 to :data:`m3p2i.load.MAX_PROCS`."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_PROCS:
        raise ValueError(f"must be an integer in [0, {MAX_PROCS}]")
    return value


def find_bench(name_or_path: str | os.PathLike) -> Path:
    """A path as given, else ``NAME.yaml`` in the user's bench folders, then the shipped ones."""
    return find(name_or_path, "bench")


def load_bench(name_or_path: str | os.PathLike) -> BenchConfig:
    """Read a bench file strictly (errors name the file, the key, the value)."""
    path = find_bench(name_or_path)
    top = Section(load_yaml(path), str(path))
    cases, names = [], set()
    for c in top.items("cases", required=True):
        # a case's hardware: (the old name of faults:) read as faults:
        c = Section(read_old_name(c.data, c.source, c.path), c.source, c.path)
        case = BenchCase(
            case=c.req("case", str),
            variant=c.opt("variant", "", str),
            scenario=c.req("scenario", str, "a scenario name or YAML path"),
            trials=c.req("trials", positive_int),
            mode=c.opt("mode", "lockstep", one_of(MODES)),
            plan_every=c.opt("plan_every", 1, positive_int),
            max_rate=c.opt("max_rate", 0.0, positive, "plans per second > 0"),
            realtime_factor=c.opt(
                "realtime_factor", 1.0, positive, "world seconds per wall second > 0"
            ),
            load=c.opt("load", 0, _busy, f"busy processes, an integer in [0, {MAX_PROCS}]"),
        )
        case = _with_faults(case, c, path)
        for key, why, value, expected in mode_conflicts(
            case.mode, case.plan_every, case.max_rate, case.realtime_factor
        ):
            raise c.error(key, why, value, expected)
        if case.case in names:
            raise c.error("case", "duplicate case name", case.case, "a unique name")
        names.add(case.case)
        c.done()
        cases.append(case)
    if not cases:
        raise top.error("cases", "needs at least one case", [])
    cfg = BenchConfig(
        source=str(path),
        cases=tuple(cases),
        timeout=top.opt("timeout", 600.0, positive, "wall-clock seconds > 0"),
        quick_trials=top.opt("quick_trials", 2, positive_int),
        sweep=parse_sweep_section(top.opt("sweep", None), str(path))
        if top.has("sweep")
        else Sweep(),
    )
    top.done()
    return cfg


# ----------------------------------------------------------------------------------- selection


@dataclass(frozen=True)
class ReadyCase:
    case: BenchCase
    scenario: Scenario
    evaluator: MetricsEvaluator  # the scenario's metrics, frames resolved
    overrides: dict = field(default_factory=dict)  # of a sweep: {key: value}


@dataclass(frozen=True)
class SkippedCase:
    case: BenchCase
    reason: str


def select_cases(
    cfg: BenchConfig,
    patterns: list[str] | None = None,
    sweep: Sweep | None = None,
    variant_dir: Path | None = None,
) -> tuple[list[ReadyCase], list[SkippedCase]]:
    """The cases matching ``patterns`` (fnmatch, e.g. ``corner*``; all when None) whose scenario
    loads and compiles; the others with the reason (scenario file missing or invalid).

    With a sweep (``sweep``, else the bench file's), each case becomes one ready case per
    combination of values: its scenario with the overrides, read by the scenario loader (a bad
    key or value raises its :class:`ConfigError`: the user's ``--set`` is wrong, not the case)
    and written to ``variant_dir`` (both processes of a trial load that file)."""
    chosen = list(cfg.cases)
    if patterns:
        chosen = [c for c in cfg.cases if any(fnmatch.fnmatchcase(c.case, p) for p in patterns)]
        if not chosen:
            raise ConfigError(
                cfg.source,
                "cases",
                "no case matches --cases",
                patterns,
                f"names or patterns of: {', '.join(c.case for c in cfg.cases)}",
            )
    sweep = cfg.sweep if sweep is None else sweep
    ready, skipped = [], []
    base = Path(cfg.source).parent
    for case in chosen:
        local = base / case.scenario
        try:
            path = local if local.is_file() else find_scenario(case.scenario)
        except ConfigError:
            skipped.append(
                SkippedCase(
                    case,
                    f"no scenario file {case.scenario!r} "
                    "(beside the bench file, or a name: m3p2i list)",
                )
            )
            continue
        try:
            scenario = load_scenario(path)
            evaluator = MetricsEvaluator(scenario)
        except (ConfigError, ValueError) as exc:  # ValueError: the model does not compile
            skipped.append(SkippedCase(case, f"invalid scenario: {exc}"))
            continue
        if not sweep.keys:
            ready.append(ReadyCase(case, scenario, evaluator))
            continue
        if variant_dir is None:
            raise ValueError("a sweep needs a folder for its scenario variants")
        for overrides in sweep.variants():
            ready.append(_variant(case, scenario, path, overrides, variant_dir))
    return ready, skipped


def check_variants(
    ready: list[ReadyCase], workers: int, check: Callable[[str], list[str]]
) -> list[str]:
    """Every message ``check`` (:func:`m3p2i.process_checks.scenario_errors`: both processes'
    ``--check``) gives for the sweep variants among ``ready``, ``workers`` at a time; each
    message names the variant's file and the overrides."""
    variants = [rc for rc in ready if rc.overrides]
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        found = list(pool.map(lambda rc: check(rc.scenario.source), variants))
    return [
        f"{rc.case.case} with --set {', '.join(f'{k}={v}' for k, v in rc.overrides.items())}: {m}"
        for rc, messages in zip(variants, found)
        for m in messages
    ]


def _variant(
    case: BenchCase, scenario: Scenario, path: Path, overrides: dict, variant_dir: Path
) -> ReadyCase:
    """``scenario`` with ``overrides``: checked by the loader as if the user had written them in
    ``path`` (so its error names that file and the key), then written to ``variant_dir`` under
    the scenario's own name, for both processes to load."""
    raw = apply_overrides(scenario.raw, overrides)
    raw.setdefault("name", scenario.name)  # the file name must not rename it
    parse_scenario(raw, f"{path} with --set {', '.join(f'{k}={v}' for k, v in overrides.items())}")
    out = variant_dir / f"{case.case}@{file_label(overrides)}" / Path(path).name
    out.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(raw, sort_keys=False)
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)
    variant = load_scenario(out)
    return ReadyCase(case, variant, MetricsEvaluator(variant), dict(overrides))


# ------------------------------------------------------------------------------------- results


class ResultsFile:
    """``results.csv``: one row per finished trial, appended under a lock and synced to disk
    before the next trial's row, so a killed bench loses at most the trials still running."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self._lock = threading.Lock()
        self._drop_torn_tail()
        self._upgrade_header()

    def rows(self) -> list[dict[str, str]]:
        if not self.path.is_file():
            return []
        with self.path.open(newline="") as f:
            return list(csv.DictReader(f))

    def append(self, row: dict) -> None:
        with self._lock:
            new = not self.path.is_file() or self.path.stat().st_size == 0
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("a", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=FIELDS)
                if new:
                    writer.writeheader()
                writer.writerow({k: _cell(row.get(k)) for k in FIELDS})
                f.flush()
                os.fsync(f.fileno())

    def _upgrade_header(self) -> None:
        """A file written before columns were added gets them (empty), so that new rows line
        up with the header instead of shifting every cell after the first new column."""
        rows = self.rows()
        if not rows or list(rows[0]) == list(FIELDS):
            return
        unknown = set(rows[0]) - set(FIELDS)
        if unknown:
            raise ConfigError(
                str(self.path),
                "",
                "not a results file of this bench: unknown columns",
                sorted(unknown),
                f"columns among: {', '.join(FIELDS)}",
            )
        tmp = self.path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=FIELDS)
            writer.writeheader()
            writer.writerows({k: r.get(k) or "" for k in FIELDS} for r in rows)
        os.replace(tmp, self.path)

    def _drop_torn_tail(self) -> None:
        """A bench killed mid-write leaves a partial last line; the next row must not be glued
        to it."""
        if not self.path.is_file():
            return
        text = self.path.read_bytes()
        if text and not text.endswith(b"\n"):
            self.path.write_bytes(text[: text.rfind(b"\n") + 1])


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def trial_key(case: str, seed: int | str, scenario_hash: str) -> tuple[str, int, str]:
    """What makes a trial the same trial: case, seed and the scenario's content."""
    return case, int(seed), scenario_hash


def latest_rows(
    rows: list[dict[str, str]], keys: set[tuple[str, int, str]]
) -> list[dict[str, str]]:
    """The rows of the trials in ``keys``, the last one per trial (a rerun appends, never edits)."""
    latest = {}
    for r in rows:
        key = trial_key(r["case"], r["seed"], r["scenario_hash"])
        if key in keys:
            latest[key] = r
    return list(latest.values())


# -------------------------------------------------------------------------------------- trials


@dataclass(frozen=True)
class Trial:
    case: BenchCase
    scenario: Scenario
    evaluator: MetricsEvaluator
    seed: int
    overrides: dict = field(default_factory=dict)  # of a sweep: {key: value}

    @property
    def log_dir(self) -> Path:
        """Where its logs go, relative to the bench's output folder."""
        return self.case_dir / f"seed-{self.seed:03d}"

    @property
    def case_dir(self) -> Path:
        """The logs of its case (a sweep variant's own), relative to the output folder."""
        name = self.case.case + (f"@{file_label(self.overrides)}" if self.overrides else "")
        return Path("logs") / name


@dataclass(frozen=True)
class BenchOptions:
    out_dir: Path
    workers: int  # trials at once (each: one server + one planner)
    timeout: float  # wall-clock seconds per trial
    trials: int | None = None  # per case; None: the case's (or quick_trials)
    quick: bool = False
    seed: int = 0  # seed of trial 0; trial i uses seed + i
    fresh: bool = False  # two new processes per trial instead of warm pairs
    plugins: tuple[str, ...] = ()  # the planners' --plugins (modules of the operator's)


def plan_trials(
    ready: list[ReadyCase], cfg: BenchConfig, opts: BenchOptions, done: set[tuple[str, int, str]]
) -> tuple[list[Trial], list[Trial]]:
    """(all trials of this run, those still to run), seed-major. Workers start on the first
    cases, one each, and then keep to their case while it has trials (its warm pair serves
    them), so an interrupted bench has results for as many cases as there are workers, and
    more."""
    planned = []
    for i in range(max(_trials(rc.case, cfg, opts) for rc in ready) if ready else 0):
        for rc in ready:
            if i < _trials(rc.case, cfg, opts):
                planned.append(
                    Trial(rc.case, rc.scenario, rc.evaluator, opts.seed + i, rc.overrides)
                )
    todo = [t for t in planned if trial_key(t.case.case, t.seed, t.scenario.hash) not in done]
    return planned, todo


def _trials(case: BenchCase, cfg: BenchConfig, opts: BenchOptions) -> int:
    if opts.trials is not None:
        return opts.trials
    return min(cfg.quick_trials, case.trials) if opts.quick else case.trials


def run_trial(
    trial: Trial,
    opts: BenchOptions,
    threads: int,
    stop: threading.Event,
    slot: PairSlot | None = None,
) -> dict | None:
    """Run one trial and return its row; None when the bench was interrupted (not recorded, so
    a rerun runs it again). With ``slot``, in the worker's warm pair for the trial's case."""
    rel = trial.log_dir
    run_dir = opts.out_dir / rel
    launch = EpisodeLaunch(
        scenario=trial.scenario.source,
        run_dir=run_dir,
        seed=trial.seed,
        timeout=opts.timeout,
        threads=threads,
        mode=trial.case.mode,
        plan_every=trial.case.plan_every,
        faults=trial.case.faults,
        delays=trial.case.delays,
        measure_delays=trial.case.measure_delays,
        max_rate=trial.case.max_rate,
        realtime_factor=trial.case.realtime_factor,
        plugins=opts.plugins,
    )
    if slot is not None:
        case_dir = opts.out_dir / trial.case_dir
        pair = slot.get(
            pair_key(trial),
            dataclasses.replace(
                launch,
                run_dir=case_dir / "pairs" / f"seed-{trial.seed:03d}",
                log=str(case_dir / "seed-{seed:03d}" / "episode.jsonl"),
            ),
        )
        result = pair.run(trial.seed, opts.timeout, stop)
    else:
        shutil.rmtree(
            run_dir, ignore_errors=True
        )  # a stale log of an interrupted attempt must not count
        result = run_episode(launch, stop)
    if result.reason == "interrupted":
        return None
    records = log_reader.read_log(result.log_path) if result.log_path.is_file() else []
    summary = log_reader.summary(records)
    metrics = (summary or {}).get("metrics") or trial.evaluator.evaluate(records).as_dict()
    initial = log_reader.header(records).get("initial")
    return {
        "case": trial.case.case,
        "variant": trial.case.variant,
        "scenario": trial.scenario.name,
        "scenario_hash": trial.scenario.hash,
        "seed": trial.seed,
        "success": not result.reason and metrics["status"] == "success",
        "status": metrics["status"],
        "reason": result.reason or ("" if summary else "no episode summary (see the logs)"),
        "position_error": metrics["position_error"],
        "orientation_error": metrics["orientation_error"],
        "collisions": metrics["collisions"],
        # only a scenario with perceived objects measures them (server.evaluation.clearance)
        "perceived_contacts": metrics.get("perceived_contacts"),
        "perceived_clearance_min": metrics.get("perceived_clearance_min"),
        "time": metrics["time"],
        "wall_time": metrics["wall_time"],
        "planner_hz": metrics["planner_hz"],
        "steps": metrics["steps"],
        "trial_wall": round(result.wall_time, 3),
        "initial": json.dumps(initial) if initial is not None else "",
        "log": str(rel / "episode.jsonl"),
        "machine": machine(),
        "versions": versions(),
        "date": time.strftime("%Y-%m-%d"),
        "mode": trial.case.mode_label,
        "overrides": to_cell(trial.overrides),
    }


def pair_key(trial: Trial) -> tuple:
    """Trials with the same key can share a warm pair: same scenario file, processes' options
    and log folder."""
    return (
        trial.case_dir,
        trial.case.scenario,
        trial.case.mode,
        trial.case.plan_every,
        trial.case.faults,
        trial.case.delays,
        trial.case.measure_delays,
        trial.case.max_rate,
        trial.case.realtime_factor,
        trial.case.load,
    )


def run_trials(
    todo: list[Trial],
    opts: BenchOptions,
    results: ResultsFile,
    on_done: Callable[[dict], None] = lambda row: None,
) -> bool:
    """Run ``todo`` on ``opts.workers`` threads, each driving one process pair (kept across the
    trials of a case unless ``opts.fresh``); rows are appended as trials finish. Real-time trials
    come last, one at a time on every core: a world that does not wait measures the planner's speed,
    which other trials would steal. Returns False when interrupted (Ctrl-C): running trials are
    stopped and left out of the file."""
    waiting = [t for t in todo if t.case.mode != "realtime" and not t.case.load]
    realtime = [t for t in todo if t.case.mode == "realtime" and not t.case.load]
    done = _run_pool(waiting, opts.workers, opts, results, on_done) and _run_pool(
        realtime, 1, opts, results, on_done
    )
    for n in sorted({t.case.load for t in todo if t.case.load}):
        loaded = [t for t in todo if t.case.load == n]
        # one at a time under the load, bounded by their time-outs should the bench hang
        with BusyLoad(n, max_seconds=min(MAX_SECONDS, opts.timeout * (len(loaded) + 1))):
            done = done and _run_pool(loaded, 1, opts, results, on_done)
    return done


class _TrialQueue:
    """The trials still to run, in order; a worker takes the first of its pair's case when one
    is left (so a warm pair serves a case to its end), else the first of a case no other worker
    serves (else the first of all): two workers on cases of two trials each then start two
    pairs per two cases, not four."""

    def __init__(self, trials: list[Trial]):
        self._trials = list(trials)
        self._lock = threading.Lock()
        self._serving: dict[int, tuple] = {}  # worker -> pair key of its last trial

    def take(self, worker: int, key: tuple | None) -> Trial | None:
        """The next trial for ``worker``, whose warm pair (if any) has ``key``."""
        with self._lock:
            if not self._trials:
                return None
            others = {k for w, k in self._serving.items() if w != worker}
            keys = [pair_key(t) for t in self._trials]
            i = next((i for i, k in enumerate(keys) if k == key), None)
            if i is None:
                i = next((i for i, k in enumerate(keys) if k not in others), 0)
            self._serving[worker] = keys[i]
            return self._trials.pop(i)


_WORKER_DONE = object()


def _run_pool(
    todo: list[Trial],
    workers: int,
    opts: BenchOptions,
    results: ResultsFile,
    on_done: Callable[[dict], None],
) -> bool:
    if not todo:
        return True
    cores = os.cpu_count() or 1
    threads = max(1, cores // workers)  # rollout threads per planner: share the cores
    stop = threading.Event()
    trials = _TrialQueue(todo)
    finished: queue.Queue = queue.Queue()  # rows, exceptions and _WORKER_DONE

    def work(worker: int) -> None:
        slot = None if opts.fresh else PairSlot()
        try:
            while (
                not stop.is_set() and (trial := trials.take(worker, slot and slot.key)) is not None
            ):
                row = run_trial(trial, opts, threads, stop, slot)
                if row is not None:
                    results.append(row)
                    finished.put(row)
        except BaseException as exc:
            finished.put(exc)
        finally:
            if slot is not None:
                slot.close()
            finished.put(_WORKER_DONE)

    pool = [
        threading.Thread(target=work, args=(i,), name=f"bench-worker-{i}", daemon=True)
        for i in range(min(workers, len(todo)))
    ]
    for t in pool:
        t.start()
    running, interrupted, error = len(pool), False, None
    try:
        while running:
            try:
                item = finished.get(timeout=0.5)
            except queue.Empty:
                continue
            if item is _WORKER_DONE:
                running -= 1
            elif isinstance(item, BaseException):
                error = error or item
                stop.set()
            else:
                on_done(item)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        stop.set()  # the running trials stop, the queued ones never start
        for t in pool:
            t.join()
    if error is not None:
        raise error
    return not interrupted


def progress(console: Console) -> Progress:
    """The bench's progress bar: last finished trial, count, elapsed and remaining time."""
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
    )
