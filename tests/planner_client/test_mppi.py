"""MPPI / M3P2I maths on small analytic torch systems (no simulator)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy.signal import savgol_filter

from planner_client.mppi import M3P2I, MPPI, ModeSpec, MPPIConfig, sampling, temperature
from planner_client.mppi.sampling import GaussianNoise, HaltonSplineNoise
from planner_client.mppi.smoothing import savgol_matrix, smooth
from planner_client.mppi.temperature import adapt_temperature, finite_costs, softmin_weights, weigh

F64 = torch.float64
DT = 0.1


def cfg_of(**kw) -> MPPIConfig:
    base = dict(horizon=15, nu=2, noise_sigma=(0.8, 0.8), u_min=(-1.0, -1.0), u_max=(1.0, 1.0))
    return MPPIConfig(**{**base, **kw})


def t(*xs: float) -> torch.Tensor:
    return torch.tensor(xs, dtype=F64)


def single_integrator(x0: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Positions ``[S, T, 2]`` after each control of ``v: [S, T, 2]`` (velocity control)."""
    return x0 + DT * torch.cumsum(v, dim=1)


# --- one mode is plain MPPI --------------------------------------------------------------------


def wiggly_costs(v: torch.Tensor) -> torch.Tensor:
    p = single_integrator(t(0.0, 0.0), v)
    return ((p - t(2.0, 1.0)) ** 2).sum(-1) + torch.sin(3.0 * p[..., 0])


@pytest.mark.parametrize(
    "kw",
    [
        dict(sampling="gaussian", null_action=False, keep_best=False),  # literal thesis Alg. 2
        dict(sampling="halton", savgol_window=5, control_cost=1.0, gamma=0.9),
        dict(sampling="halton", halton_rotate=False, bound="squash", lambda_init=0.3),
        dict(sampling="gaussian", savgol_window=7, control_cost=0.5, u_min=None, u_max=None),
    ],
)
def test_one_mode_m3p2i_is_mppi(kw):
    # M3P2I takes all its means in one product Σ ω V, MPPI (thesis Alg. 2) adds Σ ω ε to U:
    # equal since Σ ω = 1, to rounding, which 25 iterations of feedback must not amplify
    cfg = cfg_of(seed=3, **kw)
    plain, multi = MPPI(cfg, 64), M3P2I(cfg, [ModeSpec("only", 64)])
    close = dict(rtol=1e-9, atol=1e-12)
    for _ in range(25):
        va, vb = plain.sample(), multi.sample()
        torch.testing.assert_close(va, vb, **close)
        ra, rb = plain.update(wiggly_costs(va)), multi.update(wiggly_costs(vb))
        for field in ("U", "u0", "weights", "best", "etas", "mode_costs", "fused_eta"):
            torch.testing.assert_close(getattr(ra, field), getattr(rb, field), **close, msg=field)
    assert math.isclose(float(rb.mode_weights), 1.0, rel_tol=1e-12)


# --- closed loop: double integrator -------------------------------------------------------------


def double_integrator_costs(x: torch.Tensor, v: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """State x = (p, ṗ) in R⁴, acceleration control; per-step cost ``[S, T]``, terminal ×10."""
    dt = 0.05
    vel = x[2:] + dt * torch.cumsum(v, dim=1)
    pos = x[:2] + dt * torch.cumsum(vel, dim=1)
    c = ((pos - goal) ** 2).sum(-1) + 0.1 * (vel**2).sum(-1)
    c[:, -1] *= 10.0
    return c


@pytest.mark.parametrize("planner", ["mppi-gaussian", "m3p2i-halton"])
def test_double_integrator_reaches_goal(planner):
    goal = t(1.5, -1.0)
    cfg = cfg_of(
        noise_sigma=(1.5, 1.5),
        u_min=(-3.0, -3.0),
        u_max=(3.0, 3.0),
        seed=1,
        sampling="gaussian" if planner == "mppi-gaussian" else "halton",
        eta_bounds=None if planner == "mppi-gaussian" else (3.0, 10.0),
        savgol_window=0 if planner == "mppi-gaussian" else 9,
    )
    mpc = MPPI(cfg, 150) if planner == "mppi-gaussian" else M3P2I(cfg, [ModeSpec("go", 150)])
    x = torch.zeros(4, dtype=F64)
    for _ in range(120):
        u = mpc.command(lambda v, x=x: double_integrator_costs(x, v, goal)).u0
        assert torch.all(u.abs() <= 3.0)
        x = x.clone()
        x[2:] += 0.05 * u
        x[:2] += 0.05 * x[2:]
    assert float((x[:2] - goal).norm()) < 0.05
    assert float(x[2:].norm()) < 0.1


# --- bimodal: obstacle straight ahead -----------------------------------------------------------

GOAL, OBSTACLE, RADIUS = t(4.0, 0.0), t(2.0, 0.0), 0.5


def shared_costs(p: torch.Tensor) -> torch.Tensor:
    """Distance to goal plus a collision penalty (obstacle inflated by 0.1)."""
    hit = (p - OBSTACLE).norm(dim=-1) < RADIUS + 0.1
    return (p - GOAL).norm(dim=-1) + 1000.0 * hit


def side_penalty(p: torch.Tensor, side: float) -> torch.Tensor:
    """Penalises being on the wrong side (y·side < 0) while alongside the obstacle."""
    alongside = ((p[..., 0] - OBSTACLE[0]).abs() < 1.0).to(p.dtype)
    return 10.0 * torch.relu(-side * p[..., 1]) * alongside


def with_terminal(c: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    c[:, -1] += 10.0 * (p[:, -1] - GOAL).norm(dim=-1)
    return c


def drive(planner, evaluate_at, steps: int = 80):
    x, path, dominant = torch.zeros(2, dtype=F64), [], []
    for _ in range(steps):
        result = planner.command(lambda v, x=x: evaluate_at(x, v))
        x = x + DT * result.u0
        path.append(x)
        dominant.append(int(result.mode_weights.argmax()))
    return torch.stack(path), dominant


def test_bimodal_m3p2i_commits_to_a_side_where_unimodal_mppi_stalls():
    cfg = cfg_of(horizon=20, eta_bounds=(3.0, 10.0), seed=0)

    # One Gaussian asked to serve both sides (their costs summed) averages them and stalls.
    def both_sides(x, v):
        p = single_integrator(x, v)
        return with_terminal(shared_costs(p) + side_penalty(p, 1.0) + side_penalty(p, -1.0), p)

    path, _ = drive(M3P2I(cfg, [ModeSpec("both", 200)]), both_sides)
    assert float((path[-1] - GOAL).norm()) > 2.5
    assert float(path[:, 0].max()) < OBSTACLE[0] - RADIUS

    # One mode per side: the planner commits to one and drives around the obstacle.
    planner = M3P2I(cfg, [ModeSpec("left", 100), ModeSpec("right", 100)])
    left, right = planner.mode_slices

    def per_mode(x, v):
        p = single_integrator(x, v)
        c = shared_costs(p)
        c[left] += side_penalty(p[left], 1.0)
        c[right] += side_penalty(p[right], -1.0)
        return with_terminal(c, p)

    path, dominant = drive(planner, per_mode)
    assert float((path[-1] - GOAL).norm()) < 0.1
    assert float((path - OBSTACLE).norm(dim=-1).min()) > RADIUS
    alongside = (path[:, 0] - OBSTACLE[0]).abs() < RADIUS
    ys = path[alongside, 1]
    assert len(ys) > 0 and (bool((ys > 0).all()) or bool((ys < 0).all()))
    # While alongside, the dominant mode is the side taken (afterwards both modes are alike).
    winner = 0 if float(ys[0]) > 0 else 1
    assert {d for d, a in zip(dominant, alongside.tolist()) if a} == {winner}


# --- a mode that cannot succeed -----------------------------------------------------------------


def test_hopeless_mode_gets_vanishing_fused_weight():
    goal = t(5.0, 0.0)
    cfg = cfg_of(eta_bounds=(3.0, 10.0), seed=2)
    # "stuck" pins the x velocity to 0 (a wrong discrete choice): it cannot approach the goal.
    planner = M3P2I(cfg, [ModeSpec("go", 100), ModeSpec("stuck", 100, fixed={0: 0.0})])
    x, weights = torch.zeros(2, dtype=F64), []
    for _ in range(30):
        result = planner.command(lambda v, x=x: (single_integrator(x, v) - goal).norm(dim=-1))
        x = x + DT * result.u0
        weights.append(result.mode_weights)
    w = torch.stack(weights)
    assert torch.allclose(w.sum(-1), torch.ones(30, dtype=F64))
    assert float(w[3:, 1].max()) < 1e-6
    assert float(x[0]) > 2.7  # close to full speed all the way


def test_mode_with_huge_cost_offset_is_ignored_but_keeps_its_own_mean():
    cfg = cfg_of(noise_sigma=(0.3, 0.3), eta_bounds=(3.0, 10.0), seed=4)
    planner = M3P2I(cfg, [ModeSpec("good", 50), ModeSpec("bad", 50)])
    good, bad = planner.mode_slices
    target_good, target_bad = t(0.5, 0.5), t(-0.5, -0.5)
    for _ in range(30):
        v = planner.sample()
        c = torch.empty(v.shape[:2], dtype=F64)
        c[good] = ((v[good] - target_good) ** 2).sum(-1)
        c[bad] = 1e4 + ((v[bad] - target_bad) ** 2).sum(-1)
        result = planner.update(c)
    assert float(result.mode_weights[1]) < 1e-12
    assert torch.allclose(result.U, target_good.expand(15, 2), atol=0.2)
    assert torch.allclose(planner.means[1], target_bad.expand(15, 2), atol=0.2)
    assert torch.allclose(result.best[1].mean(0), target_bad, atol=0.2)


# --- update equations against a direct evaluation -----------------------------------------------


@pytest.mark.parametrize("smoothed", [False, True])
def test_update_matches_eqs_4_to_12_for_unequal_modes(smoothed):
    """With ``smoothed`` every mean is also Savitzky-Golay filtered and clamped into tight
    bounds (the SGF and projection of thesis Alg. 2 line 33), before the one-step shift."""
    box = dict(u_min=(-0.3, -0.25), u_max=(0.3, 0.35)) if smoothed else dict(u_min=None, u_max=None)
    cfg = cfg_of(
        gamma=0.9,
        alpha_u=0.6,
        lambda_init=0.7,
        null_action=False,
        keep_best=False,
        savgol_window=5 if smoothed else 0,
        **box,
    )
    modes = [ModeSpec("a", 30), ModeSpec("b", 50), ModeSpec("c", 7)]
    planner = M3P2I(cfg, modes)
    planner.update(wiggly_costs(planner.sample()))  # non-zero means and plan
    u_prev = planner.nominal.clone()

    def finish(u):
        if not smoothed:
            return u
        u = torch.as_tensor(savgol_matrix(15, 5, 2), dtype=F64) @ u
        return torch.clamp(u, t(*box["u_min"]), t(*box["u_max"]))

    v = planner.sample()
    step = wiggly_costs(v)
    result = planner.update(step)

    s = (step * 0.9 ** torch.arange(15, dtype=F64)).sum(-1)  # paper Eq. 4
    fused = torch.exp(-(s - s.min()) / 0.7)
    fused = fused / fused.sum()  # paper Eqs. 9-11
    u = finish((1 - 0.6) * u_prev + 0.6 * (fused[:, None, None] * v).sum(0))  # paper Eq. 12
    assert torch.allclose(result.weights, fused, atol=1e-14)
    assert torch.allclose(result.U, u, atol=1e-12)
    for i, rows in enumerate(planner.mode_slices):
        w = torch.exp(-(s[rows] - s[rows].min()) / 0.7)  # paper Eqs. 5-7
        assert torch.isclose(result.etas[i], w.sum())
        assert torch.isclose(result.mode_costs[i], s[rows].min())
        assert torch.isclose(result.mode_weights[i], fused[rows].sum())
        mu = finish(((w / w.sum())[:, None, None] * v[rows]).sum(0))  # paper Eq. 8
        assert torch.allclose(planner.means[i, :-1], mu[1:], atol=1e-12)  # after the shift
        assert torch.equal(planner.means[i, -1], planner.means[i, -2])
        assert torch.equal(result.best[i], v[rows][s[rows].argmin()])
    assert torch.allclose(planner.nominal[:-1], u[1:], atol=1e-12)
    assert torch.equal(planner.nominal[-1], planner.nominal[-2])
    # re-timed by a fraction of a step, the plan is read between the unshifted plan's steps
    planner.advance(0.5)
    assert torch.allclose(planner.nominal[:-1], 0.5 * (u[:-1] + u[1:]), atol=1e-12)


@pytest.mark.parametrize("modes", [[ModeSpec("only", 40)], [ModeSpec("a", 30), ModeSpec("b", 20)]])
def test_a_results_figures_read_late_are_its_own_iterations(modes):
    """The per-mode figures are made from the update's weighting when first read: read after
    later updates (and their temperature adaptation), they are still their own iteration's."""
    cfg = cfg_of(eta_bounds=(2.0, 6.0), lambda_init=0.05)
    late, early = M3P2I(cfg, modes), M3P2I(cfg, modes)
    kept = []
    for scale in (1.0, 1e3, 1e-2, 1.0):  # new cost scales: λ is re-tuned every time
        kept.append(late.update(scale * wiggly_costs(late.sample())))
        r = early.update(scale * wiggly_costs(early.sample()))
        kept[-1:] = [(kept[-1], r.diag.clone())]
    assert len({float(r.lambdas[0]) for r, _ in kept}) == 4
    for r, diag in kept:
        assert r.diag.dtype == torch.float64 and r.diag.device.type == "cpu"
        assert torch.equal(r.diag, diag)
        n = len(modes)
        assert torch.equal(r.lambdas, diag[3 * n + 1 : 4 * n + 1]) and r.num_modes == n
        assert float(r.mode_weights.sum()) == pytest.approx(1.0)


def test_diverged_rollouts_get_zero_weight():
    planner = M3P2I(cfg_of(), [ModeSpec("a", 20), ModeSpec("b", 20)])
    v = planner.sample()
    c = v.pow(2).sum(-1)
    c[3, 4], c[25, 0], c[30, 2] = math.nan, math.inf, math.nan
    result = planner.update(c)
    assert torch.isfinite(result.U).all() and torch.isfinite(result.weights).all()
    assert float(result.weights[[3, 25, 30]].sum()) == 0.0
    assert math.isclose(float(result.weights.sum()), 1.0, rel_tol=1e-12)


# --- temperature adaptation (paper Alg. 3) --------------------------------------------------------


@pytest.mark.parametrize("bounds", [(3.0, 10.0), (10.0, 30.0), (1.5, 2.0)])
def test_temperature_lands_eta_in_window_for_any_cost_spread(bounds):
    gen = torch.Generator().manual_seed(0)
    spreads = [1e-3, 1e-1, 1.0, 1e2, 1e4, 1e6]
    rows = []
    for spread in spreads:
        rows.append(spread * torch.rand(200, generator=gen, dtype=F64))  # uniform
        rows.append(
            spread * torch.logspace(-6, 0, 200, dtype=F64)[torch.randperm(200, generator=gen)]
        )
        rows.append(spread * torch.rand(200, generator=gen, dtype=F64) ** 8)  # clustered low
    costs = torch.stack(rows).numpy()
    gaps = costs - costs.min(-1, keepdims=True)
    for lam0 in (1e-8, 1.0, 1e8):
        lam = adapt_temperature(gaps, np.full(len(rows), lam0), bounds, 20)
        assert np.isfinite(lam).all() and (lam > 0).all()
        _, eta, _ = softmin_weights(costs, lam[:, None])
        assert (eta >= bounds[0]).all() and (eta <= bounds[1]).all(), eta


def test_temperature_keeps_lambda_inside_window_and_handles_unreachable_windows():
    costs = np.linspace(0.0, 1.0, 100)[None]
    lam = np.array([0.05])
    eta = softmin_weights(costs, lam[:, None])[1]
    assert np.array_equal(
        adapt_temperature(costs, lam, (float(eta[0]) - 1, float(eta[0]) + 1), 20), lam
    )

    ties = np.concatenate([np.zeros(20), np.linspace(1, 2, 80)])
    too_few = np.linspace(0.0, 1.0, 5)
    flat = np.zeros(100)
    pad = np.full(95, math.inf)
    gaps = np.stack([ties, np.concatenate([too_few, pad]), flat])
    lam = adapt_temperature(gaps, np.ones(3), (6.0, 10.0), 20)
    assert np.isfinite(lam).all()
    w, eta, _ = softmin_weights(gaps, lam[:, None])
    assert np.allclose(w.sum(-1), np.ones(3))
    assert float(eta[0]) == pytest.approx(20.0, abs=1e-6)  # only the ties count
    assert float(eta[1]) > 4.8  # all five count
    assert float(lam[2]) == 1.0  # nothing to tune


def test_one_modes_steady_weighing_is_the_general_one_bit_for_bit(monkeypatch):
    """A single mode whose λ keeps η in its window is weighed by a short path: the same
    weights, η, β, λ and best row as the general one; anything else goes the general way."""
    rng = np.random.default_rng(3)
    one = [slice(0, 200)]

    def both(costs, lam, bounds):
        short = weigh(costs, one, lam, bounds, 10)
        with monkeypatch.context() as m:
            m.setattr(temperature, "_weigh_steady", lambda *a: None)
            return short, weigh(costs, one, lam, bounds, 10)

    steady = 0
    for scale in (1e-3, 1.0, 1e4):
        costs = scale * rng.random(200) ** 3
        for bounds in ((3.0, 10.0), None):
            for lam in (scale / 20, scale * 1e-9):  # in the window (once adapted), out
                if bounds is not None and lam == scale / 20:
                    lam = adapt_temperature(
                        (costs - costs.min())[None], np.array([lam]), bounds, 20
                    )[0]
                lam = np.full(2, lam)
                steady += temperature._weigh_steady(costs, lam, bounds) is not None
                short, general = both(costs, lam, bounds)
                for field in ("w", "eta", "beta", "lam", "best", "costs"):
                    assert np.array_equal(getattr(short, field), getattr(general, field)), field
    assert steady == 9  # all but the three out of their window
    costs = rng.random(200)
    costs[[4, 9]] = [math.nan, -math.inf]
    assert temperature._weigh_steady(costs, np.full(2, 0.1), None) is None
    assert temperature._weigh_steady(rng.random(200), np.full(2, 1e-9), (3.0, 10.0)) is None
    short, general = both(costs, np.full(2, 0.1), (3.0, 10.0))
    assert np.array_equal(short.w, general.w) and short.w[:, [4, 9]].sum() == 0.0
    # each kind of non-finite cost alone: NaN, -inf and no finite cost go the general way;
    # diverged rollouts (+inf) among finite ones are weighed short, to the same bits
    for bad, short_path in ((math.nan, False), (-math.inf, False), (math.inf, True)):
        costs = rng.random(200)
        costs[[7, 50]] = bad
        assert (temperature._weigh_steady(costs, np.full(2, 0.1), None) is not None) == short_path
        short, general = both(costs, np.full(2, 0.1), None)
        for field in ("w", "eta", "beta", "lam", "best", "costs"):
            assert np.array_equal(getattr(short, field), getattr(general, field)), (bad, field)
    assert temperature._weigh_steady(np.full(200, math.inf), np.full(2, 0.1), None) is None


def test_planner_etas_stay_in_window_across_iterations():
    bounds = (3.0, 10.0)
    planner = M3P2I(
        cfg_of(eta_bounds=bounds, lambda_init=1e3),
        [ModeSpec("a", 60), ModeSpec("b", 60), ModeSpec("c", 80)],
    )
    scale = torch.tensor([1e-3] * 60 + [1.0] * 60 + [1e6] * 80, dtype=F64)[:, None]
    for _ in range(10):
        v = planner.sample()
        result = planner.update(scale * wiggly_costs(v))
        assert (result.etas >= bounds[0]).all() and (result.etas <= bounds[1]).all()
        assert bounds[0] <= float(result.fused_eta) <= bounds[1]


# --- sampling ----------------------------------------------------------------------------------


def test_halton_samples_are_deterministic_for_a_seed():
    def run(seed):
        planner = M3P2I(cfg_of(seed=seed), [ModeSpec("a", 40), ModeSpec("b", 40)])
        out = []
        for _ in range(3):
            v = planner.sample()
            out.append(v.clone())
            planner.update(wiggly_costs(v))
        return torch.stack(out)

    a = run(7)
    assert torch.equal(a, run(7))
    assert not torch.equal(a, run(8))


def test_halton_splines_are_smooth_and_unit_scale():
    halton = HaltonSplineNoise(500, 15, 2, 4, 2, 0, True, F64, torch.device("cpu")).draw()
    gauss = GaussianNoise(500, 15, 2, 0, F64, torch.device("cpu")).draw()

    def roughness(x):
        return float(torch.diff(x, n=2, dim=1).pow(2).mean())

    assert roughness(halton) < 0.1 * roughness(gauss)
    std = halton.std(dim=0)
    assert float(std.min()) > 0.7 and float(std.max()) < 1.15
    assert float(halton.mean(dim=0).abs().max()) < 0.15


def test_fixed_halton_set_is_reused_and_rotated_one_is_not():
    dev = torch.device("cpu")
    fixed = HaltonSplineNoise(50, 15, 2, 4, 2, 0, False, F64, dev)
    rotated = HaltonSplineNoise(50, 15, 2, 4, 2, 0, True, F64, dev)
    assert torch.equal(fixed.draw().clone(), fixed.draw())
    assert not torch.equal(rotated.draw().clone(), rotated.draw())


def test_halton_draws_made_in_blocks_are_the_draws_made_one_at_a_time(monkeypatch):
    dev = torch.device("cpu")
    blocked = HaltonSplineNoise(40, 6, 2, 2, 2, 3, True, F64, dev)
    assert blocked.block > 1
    monkeypatch.setattr(sampling, "MAX_BLOCK", 1)
    single = HaltonSplineNoise(40, 6, 2, 2, 2, 3, True, F64, dev)
    assert single.block == 1
    n = 2 * blocked.block + 1  # across two refills of the block
    first = [blocked.draw().clone() for _ in range(n)]
    for i, x in enumerate(first):
        assert torch.equal(x, single.draw()), f"draw {i}"
    assert len({x.sum().item() for x in first}) == n  # every draw rotated anew
    blocked.reset()  # mid-block: the stream restarts
    assert torch.equal(blocked.draw(), first[0])


def test_finite_costs_passes_finite_costs_and_maps_the_rest_to_inf():
    finite = np.array([1.0, 2.0, 1e308, 1e308])
    assert np.array_equal(finite_costs(finite), finite)
    costs = np.array([1.0, np.nan, -np.inf, np.inf, 3.0])
    assert np.array_equal(finite_costs(costs), [1.0, np.inf, np.inf, np.inf, 3.0])


@pytest.mark.parametrize("bound", ["clamp", "squash"])
def test_samples_respect_bounds_pins_null_action_and_kept_best(bound):
    cfg = cfg_of(noise_sigma=(5.0, 5.0), u_min=(-1.0, 0.2), u_max=(2.0, 0.9), bound=bound)
    modes = [ModeSpec("free", 30), ModeSpec("suction", 25, fixed={1: 0.5})]
    planner = M3P2I(cfg, modes)
    free, pinned = planner.mode_slices
    v = planner.sample()
    lo, hi = t(-1.0, 0.2), t(2.0, 0.9)
    assert bool(((v >= lo) & (v <= hi)).all())
    assert bool((v[pinned, :, 1] == 0.5).all())
    # Null action: zero where allowed, otherwise the nearest bound, pinned channel kept.
    assert torch.equal(v[free.stop - 1], t(0.0, 0.2).expand(15, 2))
    assert torch.equal(v[pinned.stop - 1], t(0.0, 0.5).expand(15, 2))

    result = planner.update(((v - t(1.5, 0.6)) ** 2).sum(-1))
    v2 = planner.sample()
    for i, rows in enumerate(planner.mode_slices):
        shifted = torch.cat([result.best[i, 1:], result.best[i, -1:]])
        assert torch.equal(v2[rows.start], shifted)
    assert bool(((result.U >= lo) & (result.U <= hi)).all())


# --- smoothing ----------------------------------------------------------------------------------


@pytest.mark.parametrize("horizon,window,order", [(15, 9, 2), (12, 5, 3), (9, 9, 2)])
def test_savgol_matrix_matches_scipy_interp_mode(horizon, window, order):
    x = np.random.default_rng(0).normal(size=(horizon, 3))
    m = savgol_matrix(horizon, window, order)
    assert np.allclose(m @ x, savgol_filter(x, window, order, axis=0, mode="interp"), atol=1e-12)
    batch = torch.as_tensor(np.stack([x, 2 * x]))
    out = smooth(torch.as_tensor(m), batch)
    assert torch.allclose(out[1], 2 * torch.as_tensor(m @ x))


# --- changing modes -----------------------------------------------------------------------------


def test_set_modes_keeps_persisting_means_and_seeds_new_ones_from_the_plan():
    planner = M3P2I(cfg_of(eta_bounds=(3.0, 10.0)), [ModeSpec("push", 40), ModeSpec("pull", 40)])
    for _ in range(5):
        result = planner.update(((planner.sample() - t(0.5, -0.5)) ** 2).sum(-1))
    mu_pull, plan = planner.means[1].clone(), planner.nominal.clone()
    lam_pull = result.lambdas[1]

    planner.set_modes([ModeSpec("pull", 30), ModeSpec("pick", 50, fixed={0: 1.0})])
    assert planner.num_samples == 80
    assert [s.stop - s.start for s in planner.mode_slices] == [30, 50]
    assert torch.equal(planner.means[0], mu_pull)
    assert torch.equal(planner.means[1], plan)
    assert np.array_equal(planner.temperatures, [lam_pull, 1.0, result.fused_lambda])
    v = planner.sample()
    assert v.shape == (80, 15, 2) and bool((v[30:, :, 0] == 1.0).all())
    after = planner.update(v.pow(2).sum(-1))
    assert after.mode_weights.shape == (2,) and after.best.shape == (2, 15, 2)


def test_misuse_is_reported():
    planner = M3P2I(cfg_of(), [ModeSpec("a", 10)])
    with pytest.raises(RuntimeError):
        planner.update(torch.zeros(10, 15, dtype=F64))
    planner.sample()
    with pytest.raises(ValueError):
        planner.update(torch.zeros(10, dtype=F64))
    with pytest.raises(ValueError):
        M3P2I(cfg_of(), [ModeSpec("a", 10), ModeSpec("a", 10)])
    with pytest.raises(ValueError):
        M3P2I(cfg_of(), [ModeSpec("a", 10, fixed={2: 0.0})])
    with pytest.raises(ValueError):
        cfg_of(savgol_window=16)
    with pytest.raises(ValueError):
        MPPI(cfg_of(eta_bounds=(3.0, 10.0)), 10)


# --- non-finite costs and the control cost with pinned channels ----------------------------------


def unpinned_costs(v: torch.Tensor) -> torch.Tensor:
    """A state cost of channels 0 and 1 only: equal for every mode, whatever channel 2 holds."""
    return ((v[..., :2] - t(0.5, -0.5)) ** 2).sum(-1)


def test_control_cost_leaves_pinned_channels_out():
    # Suction pinned on (1.0): ε is 0 there but μ is 1, so μᵀΣ⁻¹μ would charge every sample of the
    # mode T/σ² · λ₀/2 = 187.5 for a choice the noise never made.
    cfg = cfg_of(
        nu=3,
        noise_sigma=(0.8, 0.8, 0.2),
        u_min=(-1.0, -1.0, 0.0),
        u_max=(1.0, 1.0, 1.0),
        eta_bounds=(10.0, 30.0),
        control_cost=1.0,
        seed=5,
    )
    planner = M3P2I(
        cfg, [ModeSpec("off", 100, fixed={2: 0.0}), ModeSpec("on", 100, fixed={2: 1.0})]
    )
    shares = [float(planner.command(unpinned_costs).mode_weights[1]) for _ in range(30)]
    assert float(planner.means[1, 0, 2]) == 1.0
    share = sum(shares[5:]) / len(shares[5:])
    assert 0.3 < share < 0.7, shares


def test_nan_cost_leaves_temperatures_and_means_finite():
    # A mode with as many samples as η_l: NaN used to become the float maximum, the bracket's top
    # end log(d_max) + log 50 passed what exp can hold, and λ became inf, μ NaN for ever.
    cfg = cfg_of(eta_bounds=(10.0, 30.0), seed=6)
    planner = M3P2I(cfg, [ModeSpec("small", 10), ModeSpec("large", 40)])
    small, _ = planner.mode_slices
    for i in range(8):
        c = wiggly_costs(planner.sample())
        if i < 2:
            c[small.start + 3, 5] = math.nan
        result = planner.update(c)
        assert torch.isfinite(result.lambdas).all() and torch.isfinite(result.fused_lambda)
        assert torch.isfinite(result.U).all() and torch.isfinite(planner.means).all()
    assert float(result.weights[small.start + 3]) >= 0.0


def test_temperature_is_capped_for_gaps_near_the_float_maximum():
    big = np.finfo(np.float64).max
    gaps = np.array([[0.0, 1.0, 2.0, 3.0, big], [0.0, 1e300, 1e306, 1e307, 1e308]])
    for bounds in ((10.0, 30.0), (4.5, 5.0)):
        lam = adapt_temperature(gaps, np.ones(2), bounds, 20)
        assert np.isfinite(lam).all() and (lam > 0).all(), lam
        w, _, _ = softmin_weights(gaps, lam[:, None])
        assert np.isfinite(w).all()


def test_minus_inf_cost_gets_no_weight():
    # -inf is a diverged rollout, not a perfect one.
    for planner in (
        M3P2I(cfg_of(eta_bounds=(3.0, 10.0)), [ModeSpec("a", 20), ModeSpec("b", 20)]),
        MPPI(cfg_of(), 40),
    ):
        c = wiggly_costs(planner.sample())
        c[7, 3] = -math.inf
        result = planner.update(c)
        assert float(result.weights[7]) == 0.0
        assert math.isclose(float(result.weights.sum()), 1.0, rel_tol=1e-12)
        assert torch.isfinite(result.U).all()


def test_mode_without_a_finite_cost_keeps_its_mean():
    cfg = cfg_of(eta_bounds=(3.0, 10.0), savgol_window=5, seed=7)
    planner = M3P2I(cfg, [ModeSpec("ok", 30), ModeSpec("broken", 30)])
    _ok, broken = planner.mode_slices
    planner.update(wiggly_costs(planner.sample()))
    mu = planner.means.clone()
    c = wiggly_costs(planner.sample())
    c[broken] = math.nan
    result = planner.update(c)
    assert torch.equal(planner.means[1, :-1], mu[1, 1:])  # no update, only the shift
    assert float(result.mode_weights[1]) == 0.0 and float(result.etas[1]) == 0.0
    assert torch.isfinite(result.weights).all() and torch.isfinite(result.lambdas).all()
    assert not torch.equal(planner.means[0, :-1], mu[0, 1:])
    assert result.finite  # the other mode has a plan


@pytest.mark.parametrize("kind", ["m3p2i", "mppi"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_no_finite_cost_at_all_is_flagged_and_changes_nothing(kind, bad):
    cfg = cfg_of(savgol_window=5, seed=8)
    cfg = cfg if kind == "mppi" else dataclasses.replace(cfg, eta_bounds=(3.0, 10.0))
    planner = (
        MPPI(cfg, 40) if kind == "mppi" else M3P2I(cfg, [ModeSpec("a", 20), ModeSpec("b", 20)])
    )
    plan = lambda p: p.U if kind == "mppi" else p.nominal  # noqa: E731
    planner.update(wiggly_costs(planner.sample()))
    before = plan(planner).clone()
    planner.sample()
    result = planner.update(torch.full((40, 15), bad, dtype=F64))
    assert torch.isfinite(result.U).all() and torch.isfinite(result.weights).all()
    assert float(result.weights.sum()) == 0.0  # no sample is worth anything
    assert torch.equal(plan(planner)[:-1], before[1:])
    assert not result.finite
    assert planner.update(wiggly_costs(planner.sample())).finite  # planning resumes
    assert torch.isfinite(plan(planner)).all()


def test_eta_window_a_mode_cannot_reach_is_refused():
    cfg = cfg_of(eta_bounds=(10.0, 30.0))
    with pytest.raises(ValueError, match=r"mode 'small'.* 5 samples.*\(10\.0, 30\.0\)"):
        M3P2I(cfg, [ModeSpec("small", 5), ModeSpec("large", 40)])
    M3P2I(cfg, [ModeSpec("edge", 10), ModeSpec("large", 40)])  # η_l = K: approached
    planner = M3P2I(cfg, [ModeSpec("a", 40), ModeSpec("b", 40)])
    with pytest.raises(ValueError, match="mode 'c'"):
        planner.set_modes([ModeSpec("a", 40), ModeSpec("c", 8)])
    assert [m.name for m in planner.modes] == ["a", "b"]  # nothing changed


def test_the_samplers_tables_come_from_the_cache_once_computed(tmp_path, monkeypatch):
    from planner_client.mppi import cache
    from planner_client.mppi.sampling import halton_uniforms

    monkeypatch.setenv("M3P2I_CACHE", str(tmp_path / "cache"))
    calls = []

    def compute():
        calls.append(1)
        return np.arange(6.0).reshape(2, 3)

    first = cache.cached_table("t-2x3", (2, 3), compute)
    again = cache.cached_table("t-2x3", (2, 3), compute)
    assert calls == [1] and np.array_equal(first, again)
    # a file that does not read back as the table is recomputed (and rewritten)
    (path,) = (tmp_path / "cache").glob("t-2x3-*.npy")
    path.write_bytes(b"not an array")
    assert np.array_equal(cache.cached_table("t-2x3", (2, 3), compute), first) and calls == [1, 1]
    # the cached Halton points are SciPy's, bit for bit
    from scipy.stats import qmc

    assert np.array_equal(
        halton_uniforms(16, 5, 3), qmc.Halton(d=5, scramble=True, seed=3).random(16)
    )
    assert np.array_equal(
        halton_uniforms(16, 5, 3), qmc.Halton(d=5, scramble=True, seed=3).random(16)
    )
    # a cache that cannot be written only costs the computation
    monkeypatch.setenv("M3P2I_CACHE", "/proc/m3p2i-no-such-dir")
    assert np.array_equal(cache.cached_table("t-2x3", (2, 3), compute), first)


def test_fewer_samples_or_steps_read_a_longer_cached_table_not_scipy(tmp_path, monkeypatch):
    """The anytime planner sheds samples and steps in real time: their tables are the first rows
    of longer ones already cached (the same values as SciPy's), computed only when none fits."""
    from scipy.interpolate import make_interp_spline
    from scipy.stats import qmc

    from planner_client.mppi import cache
    from planner_client.mppi.sampling import halton_uniforms, spline_basis

    monkeypatch.setenv("M3P2I_CACHE", str(tmp_path))
    full = halton_uniforms(200, 24, 3)
    basis = spline_basis(8, 4, 2)  # knots 0, 4, 8
    computed = []
    real = cache.cached_table

    def spy(name, shape, compute):
        computed.append(name)
        return real(name, shape, compute)

    monkeypatch.setattr(cache, "cached_table", spy)
    fewer = halton_uniforms(150, 24, 3)
    assert np.array_equal(fewer, full[:150]) and computed == []
    assert np.array_equal(fewer, qmc.Halton(d=24, scramble=True, seed=3).random(150))
    shorter = spline_basis(7, 4, 2)  # the same knots: the first 7 steps of T = 8
    assert computed == [] and np.array_equal(shorter, basis[:7])
    own = make_interp_spline(np.arange(3) * 4, np.eye(3), k=2, axis=0)(np.arange(7))
    assert np.array_equal(shorter, own)
    assert spline_basis(5, 4, 2).shape == (5, 2) and computed == ["spline-T5-every4-k1"]
    halton_uniforms(300, 24, 3)  # more rows than any cached: computed
    assert computed[-1] == "halton-300x24-seed3"
