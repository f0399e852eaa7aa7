"""``planner.model.variants``: rollouts over model variants and the model identified online
(planner_client/variants.py). The maths as pure functions, the section's checks, the rollouts
in variants of the model, and the identification converging on a world whose box is heavier and
slides more easily than the model's (the one episode test, slow)."""

import dataclasses
import math
from contextlib import contextmanager
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
import yaml

from planner_client.build import build_controller, build_motion_planner
from planner_client.model_state import get_full_state
from planner_client.problem import build_problem
from planner_client.variants import (
    AGGREGATES,
    Identifier,
    VariantModels,
    effective_size,
    line_fit,
    posterior_mean,
    resample,
    reweight,
    transition_log_likelihood,
)
from server.inprocess import build_episode
from server.options import load_faults
from shared import protocol as P
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from shared.scenario.faults import PROFILES
from shared.scene import initial_data
from shared.timed_plan import TimedPlan

VARIANTS = {"count": 4, "params": {"mass": 0.5, "friction": 0.5}, "identify": {}}


def _push(variants=None, **planner) -> dict:
    raw = yaml.safe_load((SCENARIO_DIR / "push.yaml").read_text())
    if variants is not None:
        raw["planner"].setdefault("model", {})["variants"] = variants
    raw["planner"].update(planner)
    return raw


def _scenario(variants=VARIANTS, **planner):
    return parse_scenario(_push(variants, **planner), str(SCENARIO_DIR / "push.yaml"))


# ------------------------------------------------------------------ the maths


def test_the_aggregates_take_the_mean_the_worst_and_the_worst_share():
    # [V=4, S=2, T=2]: sample 0 costs 1..4 in the variants, sample 1 costs 4..1
    totals = torch.tensor([[1.0, 4.0], [2.0, 3.0], [3.0, 2.0], [4.0, 1.0]])
    costs = torch.stack([totals / 2, totals / 2], dim=-1)
    assert AGGREGATES["mean"](costs, 0.25).sum(-1).tolist() == [2.5, 2.5]
    assert AGGREGATES["worst"](costs, 0.25).sum(-1).tolist() == [4.0, 4.0]
    assert AGGREGATES["cvar"](costs, 0.5).sum(-1).tolist() == [3.5, 3.5]
    # a diverged variant is the worst: the sample gets no weight
    costs[1, 0, 0] = math.nan
    assert math.isnan(AGGREGATES["worst"](costs, 0.25)[0].sum())


def test_a_line_through_noisy_poses_reads_position_and_velocity_at_its_middle():
    times = 0.05 * np.arange(7)
    truth = np.array([1.0, -2.0]) + np.outer(times - 0.15, [0.3, 0.5])  # [7, 2]
    at, slope = line_fit(times, truth, 0.15)
    assert at == pytest.approx([1.0, -2.0]) and slope == pytest.approx([0.3, 0.5])
    # 15 mm of noise: the slope's spread is 0.015 / sqrt(sum (t - mean)^2), 0.057 m/s here
    rng = np.random.default_rng(0)
    slopes = [
        line_fit(times, truth + rng.normal(0, 0.015, truth.shape), 0.15)[1] for _ in range(2000)
    ]
    expected = 0.015 / math.sqrt(np.sum((times - times.mean()) ** 2))
    assert np.std(slopes, axis=0) == pytest.approx([expected, expected], rel=0.1)


def test_bayes_with_forgetting_favours_the_variant_that_predicted_best():
    predicted = np.array([[0.0, 0.0], [0.1, 0.0], [1.0, 1.0]])  # [V, D]
    lik = transition_log_likelihood(predicted, np.zeros(2), np.full(2, 0.1))
    assert lik.tolist() == [0.0, -0.5, -100.0]
    log_w = reweight(np.full(3, -math.log(3)), lik, forget=0.9)
    w = np.exp(log_w)
    assert w.sum() == pytest.approx(1.0) and w[0] > w[1] > w[2]
    assert 1.0 <= effective_size(log_w) < 3.0
    # nothing finite to learn from: the weights stay
    assert reweight(log_w, np.full(3, -np.inf), 0.9) is log_w
    # diverged prediction: that variant, not the others, loses its weight
    lik = transition_log_likelihood(np.array([[np.nan, 0.0], [0.0, 0.0]]), np.zeros(2), np.ones(2))
    assert lik.tolist() == [-np.inf, 0.0]


def test_resampling_keeps_the_heavy_variants_redraws_a_share_and_stays_in_the_prior():
    rng = np.random.default_rng(0)
    factors = np.array([[0.6], [1.0], [1.4], [1.2]] * 5)  # [V=20, P=1]
    log_w = np.log(np.where(factors[:, 0] == 1.4, 1.0, 1e-9))
    log_w -= np.log(np.exp(log_w).sum())
    out = resample(rng, factors, log_w, np.array([0.5]), floor=0.1, jitter=0.0)
    assert out.shape == factors.shape and ((out >= 0.5) & (out <= 1.5)).all()
    # all but the floor's 2 redrawn ones are copies of the one that predicted
    assert np.sum(out[:, 0] == 1.4) >= 18
    assert posterior_mean(factors, log_w)[0] == pytest.approx(1.4)


# ------------------------------------------------------------------ the section


_MASS = {"params": {"mass": 0.5}}
_AGG = "variants.aggregate"


@pytest.mark.parametrize(
    "variants, planner, key, expected",
    [
        ({"params": {"mass": 1.5}}, {}, "variants.params.mass", "a fraction in [0, 1)"),
        ({"params": {"inertia": 0.2}}, {}, "variants.params", "unknown key"),
        ({"params": {}}, {}, "variants.params", "at least one of"),
        ({"params": {"mass": 0.5}, "count": 0}, {}, "variants.count", "an integer in [1, 256]"),
        ({"params": {"mass": 0.5}, "aggregate": "median"}, {}, "variants.aggregate", "one of"),
        ({"params": {"mass": 0.5}, "aggregate": "cvar"}, {}, "variants.aggregate", "spread: all"),
        ({"params": {"mass": 0.5}, "spread": "some"}, {}, "variants.spread", "all, identified"),
        ({"params": {"mass": 0.5}, "spread": "identified"}, {}, "variants.spread", "identify"),
        ({**_MASS, "spread": "identified", "identify": {}, "aggregate": "cvar"}, {}, _AGG, "all"),
        ({**_MASS, "identify": {"window": 21}}, {}, "variants.identify.window", "[1, 20]"),
        ({**_MASS, "identify": {"window": 0}}, {}, "variants.identify.window", "[1, 20]"),
        ({"params": {"mass": 0.5}, "count": 250}, {}, "variants.count", "count <= 200"),
        ({"params": {"mass": 0.5}}, {"backend": "warp"}, "variants", "backend: mujoco"),
        (
            {"params": {"mass": 0.5}, "identify": {"forget": 0}},
            {},
            "variants.identify.forget",
            "(0, 1]",
        ),
        (
            {"params": {"mass": 0.5}, "identify": {"sigma": 1}},
            {},
            "variants.identify",
            "unknown key",
        ),
    ],
)
def test_the_section_is_checked_naming_file_key_and_value(variants, planner, key, expected):
    with pytest.raises(ConfigError) as info:
        parse_scenario(_push(variants, **planner), "push.yaml")
    msg = str(info.value)
    assert msg.startswith(f"push.yaml: planner.model.{key}") and expected in msg, msg


def test_the_warp_backend_given_on_the_command_line_is_refused_too():
    with pytest.raises(ConfigError, match="rolls out one model for all samples"):
        build_motion_planner(_scenario(), threads=2, backend="warp")


def test_without_the_section_nothing_changes():
    sc = parse_scenario(_push(), str(SCENARIO_DIR / "push.yaml"))
    assert sc.planner.model.variants is None and "variants" not in sc.planner.model.as_dict()
    controller = build_controller(sc, threads=2)
    try:
        assert controller.motion.variants is None and controller.model_estimate() is None
    finally:
        controller.close()
    # a command without a model estimate is the frame it always was
    frame = P.encode(P.Command(session="s", seq=1, ctrl=np.zeros(3)))
    assert b"model" not in frame


# ------------------------------------------------------------------ the models


@contextmanager
def _closed_loop(sc, steps: int = 5):
    """The planner's controller against the in-process world after ``steps`` steps: yields the
    controller, the world, its newest state and the last command."""
    controller = build_controller(sc, threads=2)
    episode = build_episode(sc, seed=0)
    try:
        controller.begin("lockstep", episode.dt)
        state = episode.publish()
        for _ in range(steps):
            command = controller.step(state)
            episode.play(command)
            state = episode.publish()
        yield controller, episode, state, command
    finally:
        controller.close()
        episode.close()


def test_with_spread_identified_every_sample_rolls_out_at_the_identified_factors():
    with _closed_loop(_scenario({**VARIANTS, "spread": "identified"})) as (controller, *_):
        variants = controller.motion.variants
        assert variants.per_rollout(7, "identified") == [variants.identified] * 7
        box = variants.base.body("box").id
        factor = controller.identifier.estimate()["mass"]["box"]
        assert factor != 1.0
        mass = variants.identified.body_mass[box]
        assert mass == pytest.approx(variants.base.body_mass[box] * factor)


def test_a_variant_at_the_nominal_factors_rolls_out_as_the_model():
    sc = _scenario()
    problem = build_problem(sc)
    variants = VariantModels(problem.model, sc.world.objects, sc.planner.model.variants)
    assert [p.kind + "." + p.name for p in variants.params] == ["mass.box", "friction.box"]
    variants.factors[:] = 1.0
    variants.apply()
    x0 = get_full_state(problem.model, initial_data(sc, problem.model))
    controls = np.tile([1.0, 1.0, 0.0], (3, 40, 1))  # straight at the box
    outs = []
    for model in (problem.model, variants.models[0]):
        data = [mujoco.MjData(model)]
        _, sensors = mujoco.rollout.rollout([model] * 3, data, np.tile(x0, (3, 1)), controls)
        outs.append(sensors)
    assert np.array_equal(outs[0], outs[1])
    # a heavier box in one variant moves less under the same push
    variants.factors[1] = [1.5, 1.0]
    variants.apply()
    heavy = _box_travel(variants.models[1], x0, controls[0])
    assert heavy < _box_travel(variants.models[0], x0, controls[0]) - 0.01


def test_the_variants_of_a_panda_keep_its_pads_in_charge_of_the_pinch():
    """A variant scales a cube's contacts with the table, not the pads' grip on it: the pads
    (priority 1 in the MJCF, condim 4) still outrank every object in every variant."""
    sc = load_scenario("pick_place_variants")
    problem = build_problem(sc)
    variants = VariantModels(problem.model, sc.world.objects, sc.planner.model.variants)
    pads = np.flatnonzero(problem.model.geom_priority > 0)
    objects = [problem.model.body(o.name).id for o in sc.world.objects]
    owned = np.isin(problem.model.geom_bodyid, objects)
    rest = ~owned
    rest[pads] = False
    assert len(pads) == 2 and owned.any()
    for m in variants.models:
        assert m.geom_priority[pads].min() > m.geom_priority[owned].max()
        assert m.geom_priority[owned].min() > m.geom_priority[rest].max()


def _box_travel(model, x0, controls) -> float:
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, x0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    start = data.body("box").xpos.copy()
    for u in controls:
        data.ctrl[:] = u
        mujoco.mj_step(model, data)
    return float(np.linalg.norm(data.body("box").xpos - start))


@pytest.mark.parametrize(
    "spread, aggregate", [("split", None), ("all", "cvar"), ("identified", None)]
)
def test_the_planner_plans_over_the_variants(spread, aggregate):
    variants = {**VARIANTS, "spread": spread, **({"aggregate": aggregate} if aggregate else {})}
    sc = _scenario(variants, samples=40, horizon=8)
    planner = build_motion_planner(sc, threads=2, seed=0)
    try:
        x0 = get_full_state(planner.problem.model, initial_data(sc, planner.problem.model))
        it = planner.iterate(x0)
        assert it.fault is None and np.isfinite(it.plan).all()
        assert planner._step_costs.shape == (40, 8)
        assert it.top.shape[1] == 8
    finally:
        planner.close()


def test_a_non_finite_observation_leaves_the_estimate_unchanged():
    with _closed_loop(_scenario()) as (controller, episode, state, command):
        # the estimate goes out with every command, and survives the wire
        assert set(command.model) == {"mass.box", "friction.box"}
        assert P.decode(P.encode(command)).model == pytest.approx(command.model)
        assert episode.model == command.model  # what the world logs with each step
        identifier: Identifier = controller.identifier
        before = (controller.model_estimate(), identifier.log_w.copy(), identifier.observed)
        for field in ("qpos", "qvel"):
            bad = getattr(state, field).copy()
            bad[-1] = np.nan
            controller.step(P.State(**{**state.__dict__, field: bad}))
        assert controller.model_estimate() == before[0]
        assert np.array_equal(identifier.log_w, before[1]) and identifier.observed == before[2]


# ------------------------------------------------------------------ faults


def test_the_mismatch_profile_is_model_error_alone():
    m = PROFILES["mismatch"]
    assert (m.mismatch.mass, m.mismatch.friction, m.mismatch.gain) == (0.5, 0.5, 0.25)
    assert m.delays is None and m.position_noise_m == 0 and m.drop_rate == 0
    assert m.mismatch.friction_of == "contacts"


def test_exact_factors_are_checked(tmp_path):
    path = tmp_path / "f.yaml"
    path.write_text("mismatch: {factors: {weight: {box: 2}}}")
    with pytest.raises(ConfigError, match=r"mismatch\.factors"):
        load_faults(str(path))
    path.write_text("mismatch: {factors: {mass: {crate: 2}}}")
    with pytest.raises(Exception, match="no such object to scale; one of: box"):
        build_episode("push", seed=0, faults=load_faults(str(path)))


# ------------------------------------------------------------------ identification


def _identify(
    faults: str, seconds: float, tmp_path, params=None, seed: int = 0, window: int = 1, **planner
) -> tuple[dict, dict]:
    """Push for ``seconds`` in a world with the faults file's text; the planner's estimate and
    the world's factors."""
    path = tmp_path / "faults.yaml"
    path.write_text(faults)
    params = params or {"mass": 0.5, "friction": 0.5}
    sc = _scenario({"count": 16, "params": params, "identify": {"window": window}}, **planner)
    controller = build_controller(sc, threads=2, seed=seed)
    episode = build_episode(sc, seed=seed, faults=load_faults(str(path)))
    try:
        controller.begin("lockstep", episode.dt)
        state = episode.publish()
        while state.time < seconds - 1e-9:
            episode.play(controller.step(state))
            state = episode.publish()
        return controller.identifier.estimate(), episode.world.mismatch
    finally:
        controller.close()
        episode.close()


# Identification is scored over several seeds: one push is a contact-rich episode, and its
# digits move with the CPU and the MuJoCo patch release (with the box tracked, seed 1 reads a
# nominal box as 1.33 under mujoco 4.0.0 and 1.02 under 4.0.1; another machine read 1.12-1.15
# where this one reads 0.97-1.01). So the medians over the seeds must be near the truth, and
# all seeds but one must tell the heavy world from the nominal one; both fail when the
# identifier is off (every estimate stays at 1) or its likelihood is inverted.
HEAVY = "mismatch: {factors: {mass: {box: 1.5}, friction: {box: 0.6}}, friction_of: contacts}"
TRACKED = {
    "params": {"mass": 0.5, "friction": 0.5, "gain": 0.25},
    "tracking": {
        "object_velocities": "from_poses",
        "pose_filter": 0.35,
        "velocity_filter": 0.3,
        "predict": True,
    },
}


def _over_seeds(faults: str, tmp_path, seeds: int, **kw) -> dict[str, np.ndarray]:
    """The estimates after 3 s of pushing for seeds 0 to ``seeds`` - 1: factor -> ``[seeds]``
    (``mass``, ``friction``: the box's; a drive's name: its gain)."""
    rows = []
    for seed in range(seeds):
        estimate, _ = _identify(faults, 3.0, tmp_path, seed=seed, **kw)
        rows.append({"mass": estimate["mass"]["box"], "friction": estimate["friction"]["box"]})
        rows[-1].update(estimate.get("gain", {}))
    return {k: np.array([r[k] for r in rows]) for k in rows[0]}


@pytest.mark.slow
@pytest.mark.parametrize("window", [1, 6])
def test_the_planner_identifies_a_heavier_box_that_slides_more_easily(tmp_path, window):
    """Box mass x1.5, the friction of its contacts x0.6: over the seeds, the median estimates
    after 3 s within 15 % of the truth; in the nominal world within 10 % of nominal; and on all
    seeds but one the heavy world reads at least 0.25 heavier and 0.2 less frictional than the
    nominal one (half the true differences). Predictions over one step and over six."""
    heavy = _over_seeds(HEAVY, tmp_path, 3, window=window)
    nominal = _over_seeds("mismatch: {factors: {mass: {box: 1.0}}}", tmp_path, 3, window=window)
    assert np.median(heavy["mass"]) == pytest.approx(1.5, rel=0.15), heavy
    assert np.median(heavy["friction"]) == pytest.approx(0.6, rel=0.15), heavy
    assert np.median(nominal["mass"]) == pytest.approx(1.0, rel=0.10), nominal
    assert np.median(nominal["friction"]) == pytest.approx(1.0, rel=0.10), nominal
    assert (heavy["mass"] - nominal["mass"] > 0.25).sum() >= 2, (heavy, nominal)
    assert (nominal["friction"] - heavy["friction"] > 0.2).sum() >= 2, (heavy, nominal)


@pytest.mark.slow
def test_identification_from_tracked_poses_reads_a_heavy_box_and_a_nominal_world(tmp_path):
    """The box's velocities hidden and estimated from its poses (push_lab's filters; mass,
    friction and both drives' gains varied): over five seeds, the median estimates of a nominal
    world within 10 % of nominal, of a box 1.5 times as heavy within 15 % of 1.5, and on all
    seeds but one the heavy box reads at least 0.25 heavier than the nominal one (a tracked
    nominal box strays further than a measured one, see above). Predictions start from
    the received poses and their last step's velocities, linear and angular; started from the
    mirror's filtered state they read a nominal box as 1.3-1.5 (docs/faults.md)."""
    hidden = "hide_velocities: true"
    nominal = _over_seeds(hidden, tmp_path, 5, **TRACKED)
    heavy = _over_seeds(
        hidden + "\nmismatch: {factors: {mass: {box: 1.5}}}", tmp_path, 5, **TRACKED
    )
    for factor in ("mass", "friction", "vel_x", "vel_y"):
        assert np.median(nominal[factor]) == pytest.approx(1.0, rel=0.10), (factor, nominal)
    assert np.median(heavy["mass"]) == pytest.approx(1.5, rel=0.15), heavy
    assert (heavy["mass"] - nominal["mass"] > 0.25).sum() >= 4, (heavy, nominal)


def _replay_mass_errors(window: int, noise_seed: int) -> np.ndarray:
    """A recorded pull of a box 1.46 times as heavy as the model's (tests/data/
    pull_heavy_box.npz: the world's states and controls, pull_lab_variants under harsh, seed 8)
    replayed through pull_lab_variants' identifier with ``window``, observed as harsh's tracker
    sees it (15 mm on the robot's and the box's positions, the box's velocities withheld, 30 %
    of the states lost): the mass estimate's relative error after each state from 3 s on."""
    rec = np.load(Path(__file__).parents[1] / "data" / "pull_heavy_box.npz")
    sc = load_scenario("pull_lab_variants")
    cfg = sc.planner.model.variants
    cfg = dataclasses.replace(cfg, identify=dataclasses.replace(cfg.identify, window=window))
    model = build_problem(sc).model
    dt = float(rec["time"][1] - rec["time"][0])
    identifier = Identifier(VariantModels(model, sc.world.objects, cfg), dt, from_poses=True)
    box = model.body("box").id
    qadr, vadr = model.jnt_qposadr[model.body_jntadr[box]], model.jnt_dofadr[model.body_jntadr[box]]
    noisy = np.r_[0, 1, qadr : qadr + 3]  # the robot's slide joints, the box's position
    rng = np.random.default_rng(noise_seed)
    mirror = mujoco.MjData(model)
    # a record's control is the one the world applied over the step that ended at its time
    plans = [TimedPlan(t - dt, dt, u[None, :]) for t, u in zip(rec["time"], rec["ctrl"])]
    errors = []
    for k, t in enumerate(rec["time"]):
        if rng.uniform() < 0.3:
            continue
        qpos = rec["qpos"][k].copy()
        qpos[noisy] += rng.normal(0.0, 0.015, len(noisy))
        mirror.qpos[:], mirror.qvel[:], mirror.time = qpos, rec["qvel"][k], t
        mirror.qvel[vadr : vadr + 6] = 0.0
        identifier.observe(mirror, qpos, plans[: k + 1], np.zeros(model.nu))
        if t >= 3.0:
            errors.append(identifier.estimate()["mass"]["box"] / float(rec["mass"]) - 1.0)
    return np.abs(errors)


@pytest.mark.slow
def test_a_window_reads_the_mass_of_a_pulled_box_through_a_trackers_noise():
    """Over five draws of the noise, six-step predictions from a line through the poses read
    the heavy box's mass within 20 % (median from 3 s on); one-step predictions, whose start
    velocity is one step's difference of noisy poses, do worse."""
    one = np.median([np.median(_replay_mass_errors(1, s)) for s in range(5)])
    six = np.median([np.median(_replay_mass_errors(6, s)) for s in range(5)])
    assert six < 0.2 and six < one, (six, one)
