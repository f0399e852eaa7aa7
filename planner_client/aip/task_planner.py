"""The multi-factor active-inference task planner, called once per AIP tick.

Each tick (paper Alg. 1, line 7): every factor perceives its observation (thesis Eqs. 2.13-2.14) and
updates its belief D once (thesis Eq. 2.17); if every goal is observed the task is a success.
Otherwise the planner runs *adaptive action selection with precondition back-chaining* (thesis [45])
and, with ``alternatives=True``, keeps searching for *alternative plans* (paper Alg. 2):

1. Preferences C are the goals (linear preference 1) and habits E the template's.
2. Each factor picks its most probable policy, q = σ(ln E − F − G) (thesis Eqs. 2.15-2.16); the
   first factor in template order whose pick is not idle proposes its action.
3. The proposed action is inhibited (E = 0) so the next pass looks further. If its
   preconditions hold in the current observation it is admissible: it is returned (adaptive) or
   recorded (alternatives). Otherwise each unmet precondition becomes a preference of 2 on its
   factor, which makes that factor propose an action achieving it.
4. The search ends when every factor picks idle. Each pass inhibits one action, so there are at
   most (number of actions + 1) passes.

Preferences and habits are rebuilt every tick from the goals, so a decision depends only on the
current observation; the belief D carries over and is reported.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner_client.aip.agent import IDLE_INDEX, FactorAgent, FactorModel, Perception
from planner_client.aip.maths import log_eps
from shared.task_template import StateRef, TaskTemplate

GOAL_PREFERENCE = 1.0
# Above the goal's 1, so a factor serves a blocked action's precondition before its own goal.
PUSHED_PREFERENCE = 2.0

Status = Literal["running", "success", "failure", "waiting"]
Found = list[tuple[str, tuple[str, ...]]]  # admissible action, chain of reasons leading to it
Blocked = list[tuple[str, list[StateRef]]]  # blocked action, its unmet preconditions


@dataclass(frozen=True)
class Decision:
    """The outcome of one tick.

    ``action`` is the action to execute (None unless running); ``alternatives`` are all admissible
    actions found, ``action`` first, in the order the search met them (habits, then template
    order); ``reason`` explains the choice in words; ``beliefs`` is each factor's D after this
    tick, ``{factor: {state: probability}}``.
    """

    status: Status
    action: str | None
    alternatives: tuple[str, ...]
    reason: str
    beliefs: dict[str, dict[str, float]]


class ActiveInferencePlanner:
    """Adaptive action selection over the factors of a :class:`TaskTemplate`."""

    def __init__(self, template: TaskTemplate, *, alternatives: bool = True, waits: bool = False):
        """``waits``: a team robot's planner, whose factors without actions are the other
        robots' to change: an action blocked only on them, directly or through actions of its
        own that are blocked in turn, waits (status ``waiting``) instead of failing."""
        self.template = template
        self.alternatives = alternatives
        self.waits = waits
        self._agents = {
            f.name: FactorAgent(FactorModel.from_template(f, template.idle_habit))
            for f in template.factors
        }
        self._factor_of = {a.name: f.name for f in template.factors for a in f.actions}
        self._index = {
            StateRef(f.name, s): i for f in template.factors for i, s in enumerate(f.states)
        }
        self._preconditions = {a.name: a.preconditions for a in template.actions()}
        self._n_actions = len(self._preconditions)

    def reset(self) -> None:
        """Start a new episode: every belief D back to uniform."""
        for agent in self._agents.values():
            agent.reset()

    def beliefs(self) -> dict[str, dict[str, float]]:
        return {
            f: dict(zip(agent.model.states, map(float, agent.belief)))
            for f, agent in self._agents.items()
        }

    def step(self, observation: Mapping[str, int | str]) -> Decision:
        """Decide for one tick from one observation per factor (state index or state name)."""
        obs = self._indices(observation)
        seen = {f: agent.perceive(obs[f]) for f, agent in self._agents.items()}
        prefs = {f: np.zeros(len(agent.model.states)) for f, agent in self._agents.items()}
        for goal in self.template.goals:
            prefs[goal.factor][self._index[goal]] = GOAL_PREFERENCE
        log_E = {f: agent.model.log_E.copy() for f, agent in self._agents.items()}
        q = {f: self._evaluate(f, seen[f], prefs[f], log_E[f]) for f in self._agents}
        for f, agent in self._agents.items():
            agent.learn(seen[f], q[f])  # once per tick; the search below only rewrites C and E
        beliefs = self.beliefs()

        unmet_goals = [g for g in self.template.goals if obs[g.factor] != self._index[g]]
        if not unmet_goals:
            goals = ", ".join(map(str, self.template.goals))
            return Decision("success", None, (), f"all goals hold: {goals}", beliefs)

        found, blocked = self._search(obs, seen, prefs, log_E, q)
        if found:
            names = tuple(name for name, _ in found)
            return Decision(
                "running", names[0], names, " -> ".join((names[0],) + found[0][1]), beliefs
            )
        others = [p for _, unmet in blocked for p in unmet if self._observed_only(p.factor)]
        # a chain of own actions (place needs preplace, whose move2place needs docked) waits too
        tried = {self._factor_of[name] for name, _ in blocked}
        if (
            self.waits
            and others
            and all(
                self._observed_only(p.factor) or p.factor in tried
                for _, unmet in blocked
                for p in unmet
            )
        ):
            waiting = ", ".join(map(str, dict.fromkeys(others)))
            return Decision("waiting", None, (), f"waiting for {waiting}", beliefs)
        return Decision(
            "failure", None, (), self._failure_reason(obs, unmet_goals, blocked), beliefs
        )

    def _observed_only(self, factor: str) -> bool:
        """A factor no action of the template changes (only observed)."""
        return not self.template.factor(factor).actions

    def _search(
        self,
        obs: dict[str, int],
        seen: dict[str, Perception],
        prefs: dict[str, np.ndarray],
        log_E: dict[str, np.ndarray],
        q: dict[str, np.ndarray],
    ) -> tuple[Found, Blocked]:
        """Back-chaining over preconditions; rewrites ``prefs``, ``log_E`` and ``q`` in place."""
        why: dict[str, tuple[str, ...]] = {f: () for f in self._agents}
        for goal in self.template.goals:
            why[goal.factor] = (f"goal {goal}",)
        found: Found = []
        blocked: Blocked = []
        # Every pass inhibits one action for good, so all are idle after at most n_actions passes.
        for _ in range(self._n_actions + 1):
            proposal = next(
                ((f, int(np.argmax(q[f]))) for f in self._agents if np.argmax(q[f]) != IDLE_INDEX),
                None,
            )
            if proposal is None:
                break
            f, a = proposal
            name = self._agents[f].model.actions[a]
            log_E[f][a] = -np.inf  # E = 0: never proposed again this tick
            changed = {f}
            unmet = [p for p in self._preconditions[name] if obs[p.factor] != self._index[p]]
            for p in unmet:
                prefs[p.factor][self._index[p]] = PUSHED_PREFERENCE
                why[p.factor] = (f"{p} for {name}",) + why[f]
                changed.add(p.factor)
            if unmet:
                blocked.append((name, unmet))
            else:
                found.append((name, why[f]))
                if not self.alternatives:
                    break
            for g in changed:
                q[g] = self._evaluate(g, seen[g], prefs[g], log_E[g])
        return found, blocked

    def _evaluate(
        self, factor: str, perception: Perception, prefs: np.ndarray, log_E: np.ndarray
    ) -> np.ndarray:
        return self._agents[factor].evaluate(perception, log_eps(prefs), log_E).q

    def _failure_reason(
        self, obs: dict[str, int], unmet_goals: list[StateRef], blocked: Blocked
    ) -> str:
        parts = [f"no admissible action towards {', '.join(map(str, unmet_goals))}"]
        if blocked:
            parts.append(
                "blocked: "
                + "; ".join(f"{name} needs {', '.join(map(str, unmet))}" for name, unmet in blocked)
            )
        wanted = list(dict.fromkeys(unmet_goals + [p for _, unmet in blocked for p in unmet]))
        for ref in wanted:
            current = self._agents[ref.factor].model.states[obs[ref.factor]]
            if not any(
                a.effect.target(current) == ref.state
                for a in self.template.factor(ref.factor).actions
            ):
                parts.append(f"no action takes {ref.factor} from {current} to {ref.state}")
        return "; ".join(parts)

    def _indices(self, observation: Mapping[str, int | str]) -> dict[str, int]:
        for name in observation:
            if name not in self._agents:
                raise ValueError(
                    f"observation for unknown factor {name!r} (factors: {', '.join(self._agents)})"
                )
        indices = {}
        for f, agent in self._agents.items():
            if f not in observation:
                raise ValueError(f"no observation for factor {f!r}")
            value, states = observation[f], agent.model.states
            if isinstance(value, str) and value in states:
                indices[f] = states.index(value)
            elif (
                isinstance(value, (int, np.integer))
                and not isinstance(value, bool)
                and 0 <= value < len(states)
            ):
                indices[f] = int(value)
            else:
                raise ValueError(
                    f"bad observation for factor {f!r}: {value!r} (expected a state "
                    f"index 0..{len(states) - 1} or one of: {', '.join(states)})"
                )
        return indices
