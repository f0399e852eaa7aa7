"""Benchmark this package's MPPI / M3P2I against ``pytorch_mppi`` (UM-ARM-Lab) on the same tasks.

Closed loop on two analytic systems, same K, T, λ, σ, bounds and cost for every planner:

* pendulum swing-up (pytorch_mppi's own example: K=100, T=15, σ=10, λ=1, |u| ≤ 2, dt=0.05),
* a 2-D double integrator driven to a goal (K=200, T=15, σ=1.5, λ=1, |u| ≤ 3, dt=0.05).

Rows: ``pytorch_mppi``; ``MPPI (thesis Alg. 2)`` with Gaussian noise and the control cost on, i.e.
the same algorithm as pytorch_mppi; ``M3P2I (1 mode)`` with this package's defaults plus η ∈ [3, 10]
and a Savitzky-Golay window of 9 (the thesis settings). Columns: true-system cost summed over the
episode and at its last step (mean ± std over seeds), wall time per control step (rollout included;
both libraries roll out with the same Python loop over T), and for this package the planner's own
time (sample + update, rollout excluded).

A second table compares the Halton-set choices of ``sampling.py`` (fixed set as in the paper,
rotated set, Gaussian) on the double integrator.

    python scripts/benchmark_mppi.py [--seeds 5] [--threads 1]

``pytorch_mppi`` is needed only here: ``pip install pytorch-mppi`` (it does not replace torch).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch
from rich.console import Console
from rich.table import Table

from measure.options import positive_int
from planner_client.mppi import M3P2I, MPPI, ModeSpec, MPPIConfig

F64 = torch.float64


@dataclass(frozen=True)
class Task:
    """A closed-loop problem: batched dynamics ``[B, nx], [B, nu] -> [B, nx]`` and step cost."""

    name: str
    x0: tuple[float, ...]
    dynamics: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    cost: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    nu: int
    samples: int
    horizon: int
    sigma: float
    lam: float
    u_max: float
    steps: int


def angle_normalize(x: torch.Tensor) -> torch.Tensor:
    return ((x + math.pi) % (2 * math.pi)) - math.pi


def pendulum(state: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Gym pendulum (g = 10, m = l = 1, dt = 0.05), the pytorch_mppi example."""
    th, thdot = state[:, 0], state[:, 1]
    u = u[:, 0].clamp(-2.0, 2.0)
    thdot = (thdot + (3 * 10.0 / 2 * torch.sin(th) + 3.0 * u) * 0.05).clamp(-8.0, 8.0)
    return torch.stack((th + thdot * 0.05, thdot), dim=1)


def pendulum_cost(state: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    return angle_normalize(state[:, 0]) ** 2 + 0.1 * state[:, 1] ** 2


GOAL = torch.tensor([1.5, -1.0], dtype=F64)


def double_integrator(state: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    vel = state[:, 2:] + 0.05 * u
    return torch.cat((state[:, :2] + 0.05 * vel, vel), dim=1)


def double_integrator_cost(state: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    return ((state[:, :2] - GOAL) ** 2).sum(-1) + 0.1 * (state[:, 2:] ** 2).sum(-1)


TASKS = [
    Task(
        "pendulum swing-up",
        (math.pi, 0.0),
        pendulum,
        pendulum_cost,
        1,
        100,
        15,
        10.0,
        1.0,
        2.0,
        100,
    ),
    Task(
        "2-D double integrator",
        (0.0, 0.0, 0.0, 0.0),
        double_integrator,
        double_integrator_cost,
        2,
        200,
        15,
        1.5,
        1.0,
        3.0,
        100,
    ),
]


def rollout_costs(task: Task, x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Per-step costs ``[S, T]`` of control sequences ``v: [S, T, nu]`` from state ``x``."""
    state = x.expand(v.shape[0], -1)
    costs = []
    for t in range(v.shape[1]):
        state = task.dynamics(state, v[:, t])
        costs.append(task.cost(state, v[:, t]))
    return torch.stack(costs, dim=1)


def config(task: Task, seed: int, **kw) -> MPPIConfig:
    return MPPIConfig(
        horizon=task.horizon,
        nu=task.nu,
        noise_sigma=(task.sigma,) * task.nu,
        lambda_init=task.lam,
        u_min=(-task.u_max,) * task.nu,
        u_max=(task.u_max,) * task.nu,
        seed=seed,
        **kw,
    )


def ours(planner_of: Callable[[Task, int], object]):
    """Controller factory for this package's planners:
    ``(task, seed) -> step(x) -> (u, planner_s)``."""

    def make(task: Task, seed: int):
        planner = planner_of(task, seed)

        def step(x: torch.Tensor) -> tuple[torch.Tensor, float]:
            t0 = time.perf_counter()
            v = planner.sample()
            t1 = time.perf_counter()
            c = rollout_costs(task, x, v)
            t2 = time.perf_counter()
            u0 = planner.update(c).u0
            return u0, (t1 - t0) + (time.perf_counter() - t2)

        return step

    return make


def arm(task: Task, seed: int):
    from pytorch_mppi import MPPI as ArmMPPI  # checked by main()

    torch.manual_seed(seed)
    ctrl = ArmMPPI(
        task.dynamics,
        task.cost,
        len(task.x0),
        noise_sigma=task.sigma**2 * torch.eye(task.nu, dtype=F64),
        num_samples=task.samples,
        horizon=task.horizon,
        lambda_=task.lam,
        u_min=torch.full((task.nu,), -task.u_max, dtype=F64),
        u_max=torch.full((task.nu,), task.u_max, dtype=F64),
        U_init=torch.zeros(task.horizon, task.nu, dtype=F64),
    )
    return lambda x: (ctrl.command(x), math.nan)


PLANNERS = {
    "pytorch_mppi": arm,
    "MPPI (thesis Alg. 2)": ours(
        lambda task, seed: MPPI(
            config(
                task,
                seed,
                sampling="gaussian",
                control_cost=1.0,
                null_action=False,
                keep_best=False,
            ),
            task.samples,
        )
    ),
    "M3P2I (1 mode)": ours(
        lambda task, seed: M3P2I(
            config(task, seed, eta_bounds=(3.0, 10.0), savgol_window=9),
            [ModeSpec("go", task.samples)],
        )
    ),
}


@dataclass(frozen=True)
class Episode:
    total: float  # true-system cost summed over the episode
    last: float  # true-system cost at the last step
    wall_s: float  # seconds per control step, rollout included
    planner_s: float  # seconds per step in sample + update (nan for pytorch_mppi)
    jitter: float  # Σ_t |u0_t - u0_{t-1}|²
    x: torch.Tensor  # final state


def episode(task: Task, make, seed: int) -> Episode:
    step = make(task, seed)
    x = torch.tensor(task.x0, dtype=F64)
    total = last = jitter = wall = planner = 0.0
    prev = None
    for _ in range(task.steps):
        t0 = time.perf_counter()
        u, own = step(x)
        wall += time.perf_counter() - t0
        planner += own
        u = u.reshape(1, -1)
        x = task.dynamics(x[None], u)[0]
        last = float(task.cost(x[None], u)[0])
        total += last
        if prev is not None:
            jitter += float(((u - prev) ** 2).sum())
        prev = u
    return Episode(total, last, wall / task.steps, planner / task.steps, jitter, x)


def overhead_us(planner, iters: int = 400, blocks: int = 5) -> float:
    """Median over blocks of µs per sample + update with fixed, precomputed costs."""
    v = planner.sample()
    gen = torch.Generator().manual_seed(0)
    scale = torch.logspace(0, 3, v.shape[0], dtype=F64)[:, None]
    costs = torch.rand(v.shape[:2], generator=gen, dtype=F64) * scale
    planner.update(costs)
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(iters):
            planner.sample()
            planner.update(costs)
        times.append((time.perf_counter() - t0) / iters * 1e6)
    return statistics.median(times)


def mean_std(xs: list[float], fmt: str) -> str:
    return (
        f"{statistics.mean(xs):{fmt}} ± {statistics.stdev(xs):{fmt}}"
        if len(xs) > 1
        else f"{xs[0]:{fmt}}"
    )


def closed_loop_table(task: Task, seeds: int) -> Table:
    """Every planner of :data:`PLANNERS` in closed loop on ``task``, over ``seeds`` seeds."""
    table = Table(
        title=f"{task.name}: K={task.samples} T={task.horizon} λ={task.lam} "
        f"σ={task.sigma} |u|≤{task.u_max}, {task.steps} steps"
    )
    for col in ("planner", "episode cost", "final cost", "ms / step", "planner ms / step"):
        table.add_column(col, justify="right" if col != "planner" else "left")
    for name, make in PLANNERS.items():
        runs = [episode(task, make, seed) for seed in range(seeds)]
        own = statistics.mean(r.planner_s * 1e3 for r in runs)
        table.add_row(
            name,
            mean_std([r.total for r in runs], ".1f"),
            mean_std([r.last for r in runs], ".3f"),
            f"{statistics.mean(r.wall_s * 1e3 for r in runs):.2f}",
            "—" if math.isnan(own) else f"{own:.3f}",
        )
    return table


def overhead_table() -> Table:
    """This package's planners' own time per iteration (:func:`overhead_us`) in several
    configurations, on one problem size."""
    table = Table(
        title="planner overhead per iteration (sample + update, no rollout), S=200 T=15 nu=2"
    )
    table.add_column("planner", justify="left")
    table.add_column("µs / iteration", justify="right")
    base = dict(horizon=15, nu=2, noise_sigma=(1.0, 1.0), u_min=(-1.0, -1.0), u_max=(1.0, 1.0))
    adapt = dict(eta_bounds=(3.0, 10.0), savgol_window=9)
    for name, planner in [
        (
            "MPPI, Gaussian, thesis Alg. 2 literal",
            MPPI(MPPIConfig(**base, sampling="gaussian", null_action=False, keep_best=False), 200),
        ),
        ("M3P2I, 1 mode, defaults", M3P2I(MPPIConfig(**base), [ModeSpec("a", 200)])),
        (
            "M3P2I, 1 mode, η ∈ [3, 10], SGF 9",
            M3P2I(MPPIConfig(**base, **adapt), [ModeSpec("a", 200)]),
        ),
        (
            "M3P2I, 2 modes (one pinned), η, SGF 9",
            M3P2I(MPPIConfig(**base, **adapt), [ModeSpec("a", 100), ModeSpec("b", 100, {1: 0.0})]),
        ),
        (
            "M3P2I, 3 modes 70/70/60, η, SGF 9, control cost",
            M3P2I(
                MPPIConfig(**base, **adapt, control_cost=1.0),
                [ModeSpec("a", 70), ModeSpec("b", 70), ModeSpec("c", 60)],
            ),
        ),
    ]:
        table.add_row(name, f"{overhead_us(planner):.0f}")
    return table


def sampling_table(task: Task, seeds: int) -> Table:
    """The sampling choices of ``sampling.py`` (fixed or rotated Halton set, Gaussian) for
    M3P2I in closed loop on ``task``, over ``seeds`` seeds."""
    table = Table(title=f"sampling on the {task.name} (M3P2I, 1 mode, η ∈ [3, 10], no smoothing)")
    for col in ("noise", "episode cost", "final position error", "Σ|Δu0|²"):
        table.add_column(col, justify="right" if col != "noise" else "left")
    for name, kw in [
        ("Halton, fixed set (paper)", dict(halton_rotate=False)),
        ("Halton, rotated each step", dict()),
        ("Gaussian", dict(sampling="gaussian")),
    ]:
        make = ours(
            lambda task, seed, kw=kw: M3P2I(
                config(task, seed, eta_bounds=(3.0, 10.0), **kw), [ModeSpec("go", task.samples)]
            )
        )
        runs = [episode(task, make, seed) for seed in range(seeds)]
        table.add_row(
            name,
            mean_std([r.total for r in runs], ".2f"),
            mean_std([float((r.x[:2] - GOAL).norm()) for r in runs], ".4f"),
            mean_std([r.jitter for r in runs], ".1f"),
        )
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=positive_int, default=5)
    parser.add_argument("--threads", type=positive_int, default=1, help="torch intra-op threads")
    args = parser.parse_args()
    try:
        import pytorch_mppi  # noqa: F401
    except ImportError:
        raise SystemExit(
            "error: this benchmark compares with pytorch_mppi, which is not installed: "
            "pip install pytorch-mppi==0.9.1 (it keeps the installed torch)"
        ) from None
    torch.set_num_threads(args.threads)
    console = Console(width=100)
    console.print(
        f"torch {torch.__version__}, {args.threads} thread(s), float64, {args.seeds} seeds"
    )
    for task in TASKS:
        console.print(closed_loop_table(task, args.seeds))
    console.print(overhead_table())
    console.print(sampling_table(TASKS[1], args.seeds))


if __name__ == "__main__":
    main()
