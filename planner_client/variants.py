"""Rollouts over model variants, and the variants identified online (``planner.model.variants``;
docs/scenarios.md, "Model variants").

The planner's model is the scenario's nominal one; a robot's masses, frictions and gains never
are. :class:`VariantModels` keeps ``V`` copies of the planner's model whose parameters are the
nominal ones times factors ``θ [V, P]`` (one column per parameter: an object's mass, an object's
friction, an actuator's gain). ``mujoco.rollout`` takes one model per rollout, so the copies are
compiled once and only their parameter arrays are rewritten when the factors change.

:class:`Identifier` is a particle filter over ``θ``: after each received state it steps every
variant from the previous state under the controls the world played, scores how well each
predicted the objects' positions and the robot's velocities, reweights (with forgetting, so old
evidence fades), and, when the weights have collapsed, resamples the variants, moves each a
little (jitter) and redraws a share from the prior (floor): the ensemble narrows to the world's
parameters and widens again when the world changes. The maths are the pure functions below.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from planner_client.timing import played, step_through
from shared.scenario import VARIANT_PARAMS, ObjectConfig, VariantsConfig
from shared.scene import contact_friction
from shared.timed_plan import TimedPlan

# the model's arrays that the planner changes while it runs (mocap poses for the rollouts'
# start, welds of held objects and their contact bits): copied from the planner's model into
# every variant before they roll out or predict
_RUNTIME_FIELDS = (
    "body_pos",
    "body_quat",
    "eq_data",
    "eq_active0",
    "geom_contype",
    "geom_conaffinity",
)


# ------------------------------------------------------------------ pure maths


def draw_factors(rng: np.random.Generator, count: int, half: np.ndarray) -> np.ndarray:
    """``count`` factor vectors uniform in ``[1 - half, 1 + half]``: ``[V, P]`` from the prior
    half-widths ``half [P]``."""
    return 1.0 + half[None, :] * rng.uniform(-1.0, 1.0, size=(count, len(half)))


def transition_log_likelihood(
    predicted: np.ndarray, observed: np.ndarray, sigma: np.ndarray
) -> np.ndarray:
    """Gaussian log-likelihood (up to a constant) of ``observed [D]`` under each variant's
    prediction ``predicted [V, D]`` with independent errors of spread ``sigma [D]``: ``[V]``,
    ``-inf`` for a variant whose prediction is not finite."""
    z = (predicted - observed[None, :]) / sigma[None, :]
    out = -0.5 * np.sum(z * z, axis=1)
    return np.where(np.isfinite(out), out, -np.inf)


def reweight(log_w: np.ndarray, log_lik: np.ndarray, forget: float) -> np.ndarray:
    """Bayes' rule with forgetting: normalised log-weights ``[V]`` of ``forget · log_w +
    log_lik`` (``forget`` < 1 tempers the past, a posterior that can move again). Unchanged
    when no variant has a finite likelihood."""
    if not np.isfinite(log_lik).any():
        return log_w
    a = forget * log_w + log_lik
    return a - _logsumexp(a)


def effective_size(log_w: np.ndarray) -> float:
    """Kish's effective sample size ``1 / Σ w²`` of normalised log-weights ``[V]``."""
    w = np.exp(log_w)
    return float(1.0 / np.sum(w * w))


def resample(
    rng: np.random.Generator,
    factors: np.ndarray,
    log_w: np.ndarray,
    half: np.ndarray,
    floor: float,
    jitter: float,
) -> np.ndarray:
    """New factors ``[V, P]``: systematic resampling of ``factors [V, P]`` by the weights
    ``log_w [V]``, each moved by Gaussian noise of ``jitter · half [P]`` (rejuvenation), and
    ``round(floor · V)`` of them (at least one when ``floor`` > 0) redrawn from the prior, so
    that a world that changes is found again. All kept within the prior ``[1 - half, 1 + half]``."""
    count = len(factors)
    w = np.exp(log_w)
    positions = (rng.uniform() + np.arange(count)) / count
    picks = np.minimum(np.searchsorted(np.cumsum(w / w.sum()), positions), count - 1)
    out = factors[picks] + jitter * half[None, :] * rng.standard_normal(factors.shape)
    fresh = max(1, round(floor * count)) if floor > 0 else 0
    if fresh:
        out[rng.choice(count, size=fresh, replace=False)] = draw_factors(rng, fresh, half)
    return np.clip(out, 1.0 - half, 1.0 + half)


def line_fit(times: np.ndarray, values: np.ndarray, at: float) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares line through ``values [n, D]`` received at ``times [n]`` (n >= 2):
    its value ``[D]`` at time ``at`` and its slope ``[D]``. With noise σ on each value the
    slope is off by σ / sqrt(Σ (t - t̄)²): 0.06 m/s from seven poses 0.05 s apart under 15 mm,
    against 0.42 m/s for the difference of two."""
    x = times - at
    a = np.stack([np.ones_like(x), x], axis=1)  # [n, 2]
    coef, *_ = np.linalg.lstsq(a, values, rcond=None)
    return coef[0], coef[1]


def posterior_mean(factors: np.ndarray, log_w: np.ndarray) -> np.ndarray:
    """The weighted mean ``[P]`` of ``factors [V, P]`` under ``log_w [V]``: the estimate."""
    w = np.exp(log_w)
    return (w / w.sum()) @ factors


def aggregate_mean(costs: torch.Tensor, alpha: float) -> torch.Tensor:
    """``[S, T]``: each sample's step costs averaged over the variants ``costs [V, S, T]``."""
    return costs.mean(0)


def aggregate_cvar(costs: torch.Tensor, alpha: float) -> torch.Tensor:
    """``[S, T]``: per sample, the mean step costs of its ``ceil(alpha · V)`` costliest
    variants (by total cost; a diverged variant is the costliest), the conditional value at
    risk of ``costs [V, S, T]``."""
    count = costs.shape[0]
    k = min(count, max(1, math.ceil(alpha * count)))
    totals = torch.nan_to_num(costs.sum(-1), nan=math.inf)  # [V, S]
    worst = totals.topk(k, dim=0).indices  # [k, S]
    picked = costs.gather(0, worst[:, :, None].expand(k, *costs.shape[1:]))
    return picked.mean(0)


def aggregate_worst(costs: torch.Tensor, alpha: float) -> torch.Tensor:
    """``[S, T]``: each sample's step costs in its costliest variant of ``costs [V, S, T]``."""
    return aggregate_cvar(costs, 1.0 / costs.shape[0])


AGGREGATES = {"mean": aggregate_mean, "cvar": aggregate_cvar, "worst": aggregate_worst}


def _logsumexp(a: np.ndarray) -> float:
    top = float(np.max(a))
    return top + math.log(float(np.sum(np.exp(a - top))))


# ------------------------------------------------------------------ the models


@dataclass(frozen=True)
class Param:
    """One column of the factors: ``kind`` (mass, friction, gain) of ``name`` (an object or an
    actuator), with its prior half-width."""

    kind: str
    name: str
    half: float
    index: int  # the body (mass, friction) or actuator (gain) id


def variant_params(
    model: mujoco.MjModel, objects: Sequence[ObjectConfig], cfg: VariantsConfig
) -> list[Param]:
    """The parameters that vary, as the world's faults scale them (server.faults): the masses of
    the free scenario objects, the frictions of the ones that touch anything, every actuator's
    gain."""
    out = []
    if cfg.mass:
        out += [
            Param("mass", o.name, cfg.mass, model.body(o.name).id) for o in objects if not o.fixed
        ]
    if cfg.friction:
        out += [
            Param("friction", o.name, cfg.friction, model.body(o.name).id)
            for o in objects
            if not o.visual
        ]
    if cfg.gain:
        out += [Param("gain", model.actuator(a).name, cfg.gain, a) for a in range(model.nu)]
    return out


class VariantModels:
    """``cfg.count`` copies of ``model`` (the planner's, with its sensors), their parameters the
    nominal ones times :attr:`factors` ``[V, P]``, first drawn from the prior with ``cfg.seed``.

    A variant's friction factor scales the friction of the object's contacts
    (:func:`shared.scene.contact_friction`: scaling the object's own friction, 0.5 under the
    floor's 1.0, would change nothing). With ``spread: identified`` one more copy,
    :attr:`identified`, holds the factors the identifier estimates (:meth:`set_estimate`), and
    every sample rolls out in it."""

    def __init__(self, model: mujoco.MjModel, objects: Sequence[ObjectConfig], cfg: VariantsConfig):
        self.base = model
        self.cfg = cfg
        self.params = variant_params(model, objects, cfg)
        self.half = np.array([p.half for p in self.params])  # [P]
        self.rng = np.random.default_rng([cfg.seed])
        self.factors = draw_factors(self.rng, cfg.count, self.half)  # [V, P]
        self.models = [copy.copy(model) for _ in range(cfg.count)]
        self.identified = copy.copy(model) if cfg.spread == "identified" else None
        self._mass = model.body_mass.copy()
        self._inertia = model.body_inertia.copy()
        self._gain = model.actuator_gainprm.copy()
        self._bias = model.actuator_biasprm.copy()
        self._friction = model.geom_friction.copy()
        self._scratch = mujoco.MjData(model)
        self._geoms = {}  # friction param -> its geoms
        touching = [p.index for p in self.params if p.kind == "friction"]
        if touching:
            priority, frictions = contact_friction(model, touching)
            for p in self.params:
                if p.kind == "friction":
                    geoms, self._friction[geoms] = frictions[p.index]
                    self._geoms[p.name] = geoms
            for m in self._all():
                m.geom_priority[:] = priority
        self.apply()
        self.set_identified(self.factors.mean(0))

    def apply(self) -> None:
        """Write :attr:`factors` into the variants' parameter arrays (no recompilation), and
        the constants MuJoCo derives from them (``mj_setConst``: a mass changed without its
        inverse weights made the contacts diverge)."""
        for m, row in zip(self.models, self.factors):
            self._write(m, row)

    def set_identified(self, factors: np.ndarray) -> None:
        """The identified factors ``[P]`` into :attr:`identified` (``spread: identified``; a
        no-op otherwise)."""
        if self.identified is not None:
            self._write(self.identified, factors)

    def _write(self, m: mujoco.MjModel, row: np.ndarray) -> None:
        for p, f in zip(self.params, row):
            if p.kind == "mass":
                m.body_mass[p.index] = self._mass[p.index] * f
                m.body_inertia[p.index] = self._inertia[p.index] * f
            elif p.kind == "friction":
                geoms = self._geoms[p.name]
                m.geom_friction[geoms] = self._friction[geoms] * f
            else:  # gain: a servo's kp and kv, a motor's gear (server.faults.draw_mismatch)
                m.actuator_gainprm[p.index, 0] = self._gain[p.index, 0] * f
                m.actuator_biasprm[p.index, :3] = self._bias[p.index, :3] * f
        mujoco.mj_setConst(m, self._scratch)

    def _all(self) -> list[mujoco.MjModel]:
        return self.models + ([self.identified] if self.identified is not None else [])

    def sync(self) -> None:
        """The planner model's run-time arrays (mocap poses, welds) into every variant."""
        for name in _RUNTIME_FIELDS:
            src = getattr(self.base, name)
            for m in self._all():
                getattr(m, name)[:] = src

    def per_rollout(self, samples: int, spread: str) -> list[mujoco.MjModel]:
        """The model of each rollout: ``split``, sample ``k`` in variant ``k mod V``
        (``samples`` rollouts); ``all``, every sample in every variant, variant-major
        (``V · samples`` rollouts); ``identified``, every sample in :attr:`identified`."""
        if spread == "identified":
            return [self.identified] * samples
        if spread == "split":
            return [self.models[k % len(self.models)] for k in range(samples)]
        return [m for m in self.models for _ in range(samples)]

    def named(self, factors: np.ndarray) -> dict[str, dict[str, float]]:
        """``factors [P]`` by name, as the episode log's header holds the world's:
        kind -> name -> factor."""
        out: dict[str, dict[str, float]] = {k: {} for k in VARIANT_PARAMS}
        for p, f in zip(self.params, factors):
            out[p.kind][p.name] = float(f)
        return {k: v for k, v in out.items() if v}


class Identifier:
    """The variants reweighted by the transitions observed (module docstring). ``world_dt``:
    the world's step; ``max_gap``: states further apart (world steps) are not scored.

    ``from_poses``: the mirror estimates the free objects' velocities from their poses
    (``planner.tracking.object_velocities: from_poses``). Its filters lag a box that speeds up,
    and a prediction started from them, scored against them, favours variants whose box
    accelerates less (a heavier box, weaker drives: a nominal world read as mass 1.2-1.5,
    gains 0.75-0.85). So each prediction starts instead from the objects' poses as received
    and their velocities over the last step, linear and angular (the second difference of the
    poses is then what the variants are scored on; an angular velocity left to the filters
    read a nominal box's friction 5 % high), and the objects' velocities are not scored (they
    would count the positions' error twice).

    ``identify.window`` > 1: each prediction spans that many steps instead, from the newest
    state received at least ``window`` steps back. Under a tracker's noise (15 mm) one step's
    difference of poses makes a velocity error of 0.4 m/s, which swamps what a box's mass
    changes in one step; so, with ``from_poses``, the objects' positions and velocities at the
    start are a line fitted through the poses received within ``window // 2`` steps of it
    (:func:`line_fit`), and a heavier box's lag has ``window`` steps to build up."""

    def __init__(
        self,
        variants: VariantModels,
        world_dt: float,
        max_gap: int = 10,
        from_poses: bool = False,
    ):
        cfg = variants.cfg.identify
        self.variants = variants
        self.cfg = cfg
        self.world_dt = world_dt
        self.max_gap = max_gap
        model = variants.base
        count = len(variants.models)
        self.log_w = np.full(count, -math.log(count))  # [V]
        self.observed = 0  # transitions scored
        self.resampled = 0
        self.from_poses = from_poses
        free = model.jnt_type == mujoco.mjtJoint.mjJNT_FREE
        self._positions = np.concatenate(
            [model.jnt_qposadr[j] + np.arange(3) for j in np.flatnonzero(free)] or [[]]
        ).astype(int)  # [O·3] the free objects' positions in qpos
        self._quats = model.jnt_qposadr[free] + 3  # [O] the free objects' quaternions in qpos
        self._linear = np.concatenate(
            [model.jnt_dofadr[j] + np.arange(3) for j in np.flatnonzero(free)] or [[]]
        ).astype(int)  # [O·3] the free objects' linear velocities in qvel
        self._angular = np.concatenate(
            [model.jnt_dofadr[j] + np.arange(3, 6) for j in np.flatnonzero(free)] or [[]]
        ).astype(int)  # [O·3] the free objects' angular velocities in qvel
        robot = np.array([model.jnt_dofadr[j] for j in range(model.njnt) if not free[j]])
        # [R (+ O·3)] the robot's own velocities (and the free objects' linear ones)
        self._velocities = robot if from_poses else np.concatenate([robot, self._linear])
        self._velocities = self._velocities.astype(int)
        self._sigma = np.concatenate(
            [
                np.full(len(self._positions), cfg.position_sigma),
                np.full(len(self._velocities), cfg.velocity_sigma),
            ]
        )  # [D]
        S = mujoco.mjtState
        self._kind = (
            S.mjSTATE_FULLPHYSICS
            | S.mjSTATE_EQ_ACTIVE
            | S.mjSTATE_MOCAP_POS
            | S.mjSTATE_MOCAP_QUAT
            | S.mjSTATE_USERDATA
        )
        self._scratch = mujoco.MjData(model)
        self._prev: tuple[float, np.ndarray] | None = None
        # from_poses: the last received (time, positions [O·3], quaternions [O, 4])
        self._received: tuple[float, np.ndarray, np.ndarray] | None = None
        # window > 1: (time, start state, received positions [O·3]) of the states received
        # over the longest span a window and its fit reach back
        window = cfg.window
        self._history: deque[tuple[float, np.ndarray, np.ndarray]] = deque(
            maxlen=window + max_gap + window // 2 + 1
        )
        self._estimate = posterior_mean(variants.factors, self.log_w)  # [P]

    def observation(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """``[D]``: the free objects' positions, then the robot's velocities and the free
        objects' linear velocities (the mirror's: received, or estimated from the poses)."""
        return np.concatenate([qpos[self._positions], qvel[self._velocities]])

    def observe(
        self,
        data: mujoco.MjData,
        received_qpos: np.ndarray | None,
        plans: list[TimedPlan],
        safe: np.ndarray,
        actuation_delay: float = 0.0,
    ) -> None:
        """``data``: the mirror of the newest state; ``received_qpos``: its ``qpos`` before
        the mirror's filters (the positions observed). Scores every variant on the steps from
        the previous state (with ``window`` > 1, the state that many steps back) to this one,
        played under ``plans`` (``safe`` before any) acting ``actuation_delay`` s late. A
        state with a non-finite observation changes nothing."""
        qpos = data.qpos if received_qpos is None else received_qpos
        observed = self.observation(qpos, data.qvel)
        time = float(data.time)
        state = self._start_state(data, qpos, time)
        if not (np.isfinite(observed).all() and np.isfinite(state).all()):
            return
        if self.cfg.window == 1:
            prev, self._prev = self._prev, (time, state)
        else:
            prev = self._window_start(time, state, qpos)
        if prev is None:
            return
        steps = round((time - prev[0]) / self.world_dt)
        # a new episode, the same state, or too long a gap
        if not self.cfg.window <= steps <= self.reach:
            return
        self.variants.sync()
        d = self._scratch
        predicted = np.empty((len(self.variants.models), len(observed)))
        # the same controls for every copy: looked up once
        controls = played(
            self.variants.base, plans, safe, prev[0], self.world_dt, steps, actuation_delay
        )
        for v, m in enumerate(self.variants.models):
            mujoco.mj_setState(m, d, prev[1], self._kind)
            step_through(m, d, controls, self.world_dt)
            predicted[v] = self.observation(d.qpos, d.qvel)
        lik = transition_log_likelihood(predicted, observed, self._sigma)
        self.log_w = reweight(self.log_w, lik, self.cfg.forget)
        self.observed += 1
        # the estimate is the posterior's, before resampling redraws a share from the prior
        self._estimate = posterior_mean(self.variants.factors, self.log_w)
        self.variants.set_identified(self._estimate)
        if effective_size(self.log_w) < len(self.log_w) / 2:
            v = self.variants
            v.factors = resample(
                v.rng, v.factors, self.log_w, v.half, self.cfg.floor, self.cfg.jitter
            )
            v.apply()
            self.log_w = np.full(len(self.log_w), -math.log(len(self.log_w)))
            self.resampled += 1

    @property
    def reach(self) -> int:
        """The furthest back, in world steps, that a scored prediction starts."""
        return self.cfg.window + self.max_gap - 1

    def _window_start(
        self, time: float, state: np.ndarray, qpos: np.ndarray
    ) -> tuple[float, np.ndarray] | None:
        """Records this state (``state`` to start from, positions received in ``qpos``) and
        returns ``(time, state)`` of the newest state received at least ``window`` steps before
        ``time``, with ``from_poses`` its free objects' positions and linear velocities from
        :func:`line_fit` through the positions received within ``window // 2`` steps of it;
        None for the same state again, when there is none, or fewer than three poses to fit."""
        if self._history and time <= self._history[-1][0]:  # the same state, or a new episode
            if time == self._history[-1][0]:
                return None
            self._history.clear()
        self._history.append((time, state, np.array(qpos[self._positions], dtype=float)))
        window = self.cfg.window
        times = np.array([h[0] for h in self._history])
        back = np.round((time - times) / self.world_dt)  # steps before now
        starts = np.flatnonzero(back >= window)
        if not len(starts):
            return None
        i = starts[-1]
        t0, state, _ = self._history[i]
        if not self.from_poses or not len(self._positions):
            return t0, state
        near = np.flatnonzero(np.abs(back - back[i]) <= max(1, window // 2))
        if len(near) < 3:
            return None
        positions, velocities = line_fit(
            times[near], np.stack([self._history[j][2] for j in near]), t0
        )
        base, d = self.variants.base, self._scratch
        mujoco.mj_setState(base, d, state, self._kind)
        d.qpos[self._positions] = positions
        d.qvel[self._linear] = velocities
        out = np.empty_like(state)
        mujoco.mj_getState(base, d, out, self._kind)
        return t0, out

    def _start_state(self, data: mujoco.MjData, qpos: np.ndarray, time: float) -> np.ndarray:
        """The state the next transition's predictions start from: the mirror's ``data``, or,
        with ``from_poses``, the mirror's with the free objects' poses as received in ``qpos``
        and their linear and angular velocities from the last step's poses (0 after a gap or at
        the start). A received pose without orientation (zeros) keeps the mirror's."""
        base = self.variants.base
        state = np.zeros(mujoco.mj_stateSize(base, self._kind))
        mujoco.mj_getState(base, data, state, self._kind)
        if not self.from_poses or not len(self._positions):
            return state
        positions = np.array(qpos[self._positions], dtype=float)  # [O·3]
        d = self._scratch
        mujoco.mj_setState(base, d, state, self._kind)
        d.qpos[self._positions] = positions
        for a in self._quats:
            norm = np.linalg.norm(qpos[a : a + 4])
            if norm > 0:
                d.qpos[a : a + 4] = qpos[a : a + 4] / norm
        quats = np.stack([d.qpos[a : a + 4] for a in self._quats])  # [O, 4]
        last, self._received = self._received, (time, positions, quats)
        d.qvel[self._linear] = 0.0
        d.qvel[self._angular] = 0.0
        if last is not None and 1 <= round((time - last[0]) / self.world_dt) <= self.max_gap:
            span = time - last[0]
            d.qvel[self._linear] = (positions - last[1]) / span
            turn = np.zeros(3)
            for o, a in enumerate(self._angular.reshape(-1, 3)):
                mujoco.mju_subQuat(turn, quats[o], last[2][o])  # in the body's frame
                d.qvel[a] = turn / span
        mujoco.mj_getState(base, d, state, self._kind)
        return state

    def estimate(self) -> dict[str, dict[str, float]]:
        """The posterior mean of the factors after the last transition scored (the prior's
        before any): kind -> name -> factor."""
        return self.variants.named(self._estimate)
