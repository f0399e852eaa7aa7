"""One state factor as an active-inference agent (thesis Eq. 2.12, thesis Alg. 1).

The factor's generative model is built from its action template: A is the identity (each factor
is observed directly by a symbolic observer), B has one column-stochastic matrix per action with
the implicit idle first, E are the normalised habits. The agent keeps only D, its belief about
the current state, between ticks; preferences C and habit changes are the caller's (the planner
rewrites them during its search).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from planner_client.aip import maths
from shared.task_template import IDLE, Effect, FactorTemplate

IDLE_INDEX = 0
# Well above maths.EPS, so that an observation always outweighs the prior (see update_prior).
BELIEF_FLOOR = 1e-6


def transition_matrix(effect: Effect, states: tuple[str, ...]) -> np.ndarray:
    """B for one action, ``[n_states, n_states]``: column j is one-hot at the state j goes to."""
    B = np.zeros((len(states), len(states)))
    for j, s in enumerate(states):
        B[states.index(effect.target(s)), j] = 1.0
    return B


@dataclass(frozen=True, eq=False)
class FactorModel:
    """The MDP of one factor; arrays are read-only."""

    name: str
    states: tuple[str, ...]
    actions: tuple[str, ...]  # actions[IDLE_INDEX] is the implicit idle
    A: np.ndarray  # [n_states, n_states], identity
    B: np.ndarray  # [n_states, n_states, n_actions]
    log_E: np.ndarray  # [n_actions], ln of the normalised habits
    kappa_d: float

    @classmethod
    def from_template(cls, factor: FactorTemplate, idle_habit: float) -> FactorModel:
        n = len(factor.states)
        B = np.stack(
            [np.eye(n)] + [transition_matrix(a.effect, factor.states) for a in factor.actions],
            axis=2,
        )
        habits = np.array([idle_habit] + [a.habit for a in factor.actions])
        arrays = (np.eye(n), B, maths.log_eps(maths.normalise_columns(habits)))
        for array in arrays:
            array.flags.writeable = False
        return cls(
            factor.name,
            factor.states,
            (IDLE, *(a.name for a in factor.actions)),
            *arrays,
            factor.kappa_d,
        )


class Perception(NamedTuple):
    """What one observation tells a factor, independent of preferences and habits."""

    obs: int
    posterior: maths.StatePosterior
    F: np.ndarray  # [n_actions], thesis Eq. 2.13
    outcomes: np.ndarray  # [n_obs, n_actions], o^π = A B_π s_0^π
    G_flat: np.ndarray  # [n_actions], thesis Eq. 2.15 with C = 0


class Policies(NamedTuple):
    G: np.ndarray  # [n_actions], thesis Eq. 2.15
    q: np.ndarray  # [n_actions], thesis Eq. 2.16


class FactorAgent:
    """Perception (thesis Eqs. 2.13-2.14), policy selection (2.15-2.16) and learning of D (2.17)."""

    def __init__(self, model: FactorModel):
        self.model = model
        self.reset()

    def reset(self) -> None:
        """Forget what was observed: D uniform."""
        self._D = np.full(len(self.model.states), 1.0 / len(self.model.states))

    @property
    def belief(self) -> np.ndarray:
        """D, the belief about the current state, ``[n_states]`` (a copy)."""
        return self._D.copy()

    def perceive(self, obs: int) -> Perception:
        A = self.model.A
        post = maths.state_posterior(A, self.model.B, self._D, obs)
        G_flat = maths.expected_free_energy(A, post.predicted, np.zeros(A.shape[0]))
        return Perception(obs, post, maths.free_energy(self._D, post), A @ post.predicted, G_flat)

    def evaluate(self, perception: Perception, C: np.ndarray, log_E: np.ndarray) -> Policies:
        """G and q for log preferences C ``[n_obs]`` and log habits log_E ``[n_actions]``.

        The planner re-evaluates a factor many times per tick with new C and E; G being affine
        in C (thesis Eq. 2.15), only the preference term is recomputed.
        """
        G = perception.G_flat - C @ perception.outcomes
        return Policies(G, maths.policy_posterior(perception.F, G, log_E))

    def learn(self, perception: Perception, q: np.ndarray) -> None:
        """D ← norm(D + κ_d s̄_0), s̄_0 the model average (thesis Eq. 2.17); call once per tick."""
        s0 = maths.model_average(perception.posterior.s0, q)
        self._D = maths.update_prior(self._D, s0, self.model.kappa_d, BELIEF_FLOOR)
