"""Discrete active inference for one state factor, horizon two (thesis Sec. 2.1.2).

Pure functions on numpy arrays; nothing here mutates its inputs. Shapes:

- ``A``: ``[n_obs, n_states]``, likelihood p(o|s), columns sum to 1.
- ``B``: ``[n_states, n_states, n_policies]``, ``B[:, :, p]`` is p(s_{τ+1}|s_τ) under policy p.
  A policy is a single action, taken at τ=0 (now) and judged at τ=1 (next).
- ``D``: ``[n_states]``, prior over the current state.
- ``C``: ``[n_obs]``, log preferences over observations.
- ``log_E``: ``[n_policies]``, log habits (``-inf`` forbids a policy).

Logarithms are the safe ``ln(x + EPS)`` of the reference, so ``ln 0 = ln EPS ≈ -36.84``; the
same EPS appears in F (a state-changing action contradicts the assumed next observation) and in
G (idling keeps a non-preferred outcome), and the two cancel, so one EPS must be used throughout.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

EPS = 1e-16


def log_eps(x: np.ndarray) -> np.ndarray:
    """Safe element-wise logarithm ``ln(x + EPS)``; finite at zero."""
    return np.log(np.asarray(x, dtype=float) + EPS)


def softmax(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """σ(x) along ``axis``, on a float copy shifted by the maximum, so large values cannot overflow.

    ``-inf`` entries get probability 0; each slice needs at least one finite entry.
    """
    x = np.asarray(x, dtype=float)
    e = np.exp(x - x.max(axis=axis, keepdims=True))
    return e / e.sum(axis=axis, keepdims=True)


def normalise_columns(x: np.ndarray) -> np.ndarray:
    """A float copy whose columns (axis 0) sum to 1; an all-zero column becomes uniform."""
    x = np.asarray(x, dtype=float)
    total = x.sum(axis=0, keepdims=True)
    return np.divide(x, total, out=np.full_like(x, 1.0 / x.shape[0]), where=total > 0)


class StatePosterior(NamedTuple):
    """Beliefs per policy (thesis Eq. 2.14), each ``[n_states, n_policies]`` unless noted."""

    s0: np.ndarray  # s_0^π, the current state
    s1: np.ndarray  # s_1^π, the next state
    predicted: np.ndarray  # B_π s_0^π, the prior over the next state
    lik0: np.ndarray  # Aᵀ o_0, likelihood of the current observation, [n_states]
    lik1: np.ndarray  # Aᵀ o_1^π, likelihood of the assumed next observation


def state_posterior(A: np.ndarray, B: np.ndarray, D: np.ndarray, obs: int) -> StatePosterior:
    """One message-passing sweep of thesis Eq. 2.14 for observation index ``obs``, from s_1 uniform.

    s_0^π = σ(ln D + ln B_πᵀ s_1 + ln Aᵀ o_0) and s_1^π = σ(ln B_π s_0^π + ln Aᵀ o_1^π). The next
    observation is not known yet; as in the reference, o_1^π is the outcome most likely under
    s_0^π, i.e. the world is assumed to stay as observed unless an action changes it.
    """
    n_states = B.shape[0]
    s1_prior = np.full(n_states, 1.0 / n_states)
    lik0 = A[obs]
    backward = np.einsum("ijp,i->jp", B, s1_prior)
    s0 = softmax(log_eps(D)[:, None] + log_eps(backward) + log_eps(lik0)[:, None])
    predicted = np.einsum("ijp,jp->ip", B, s0)
    o1 = np.argmax(A @ s0, axis=0)
    lik1 = A[o1].T
    s1 = softmax(log_eps(predicted) + log_eps(lik1))
    return StatePosterior(s0, s1, predicted, lik0, lik1)


def free_energy(D: np.ndarray, post: StatePosterior) -> np.ndarray:
    """Variational free energy per policy, thesis Eq. 2.13, ``[n_policies]``.

    F(π) = Σ_τ s_τ^π · (ln s_τ^π − ln m_τ − ln Aᵀ o_τ), with m_0 = D and m_1 = B_π s_0^π.
    """
    f0 = post.s0 * (log_eps(post.s0) - log_eps(D)[:, None] - log_eps(post.lik0)[:, None])
    f1 = post.s1 * (log_eps(post.s1) - log_eps(post.predicted) - log_eps(post.lik1))
    return f0.sum(axis=0) + f1.sum(axis=0)


def ambiguity(A: np.ndarray) -> np.ndarray:
    """Entropy of each state's outcome distribution, −diag(Aᵀ ln A), ``[n_states]``, ≥ 0."""
    return -(A * log_eps(A)).sum(axis=0)


def expected_free_energy(A: np.ndarray, predicted: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Expected free energy per policy at τ=1, thesis Eq. 2.15, ``[n_policies]``.

    G(π) = o^πᵀ (ln o^π − C) − diag(Aᵀ ln A) · s^π with s^π = B_π s_0^π and o^π = A s^π: risk
    (distance of the predicted outcome from the preferences) plus ambiguity (a non-negative
    penalty for states whose outcomes are uncertain). G is affine in C: G(C) = G(0) − Cᵀ o^π.
    """
    outcomes = A @ predicted
    risk = (outcomes * (log_eps(outcomes) - C[:, None])).sum(axis=0)
    return risk + ambiguity(A) @ predicted


def policy_posterior(F: np.ndarray, G: np.ndarray, log_E: np.ndarray) -> np.ndarray:
    """q(π) = σ(ln E − F − G), thesis Eq. 2.16 with the habit prior E, ``[n_policies]``."""
    return softmax(log_E - F - G)


def model_average(s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Bayesian model average s_τ = Σ_π q(π) s_τ^π, thesis Eq. 2.17.

    ``s``: ``[n_states, n_policies]``, ``q``: ``[n_policies]`` → ``[n_states]``.
    """
    return s @ q


def update_prior(D: np.ndarray, s0: np.ndarray, kappa_d: float, floor: float) -> np.ndarray:
    """D ← norm(D + κ_d s̄_0), kept at least ``floor`` per state.

    The floor keeps ln D far above ln EPS, so the identity likelihood of a new observation always
    outweighs the prior: a flipped observation is believed on the tick it arrives (the reference
    zeroed small entries, after which prior and observation tied).
    """
    return normalise_columns(np.maximum(normalise_columns(D + kappa_d * s0), floor))
