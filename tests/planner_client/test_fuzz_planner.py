"""What reaches a running planner, fuzzed (Hypothesis): states after a good handshake with one
numeric field at float64's edges, and user cost terms returning random shapes, dtypes and
types. A state is refused by the decoder, or answered with a finite command within the
actuators' ranges, in lock-step and in real time; a term's value passes the start-up check only
as a float64 tensor ``[S, T]``, and is refused otherwise with a ``ConfigError`` that names it,
never a bare torch or numpy error.

Derandomized, no example database, sized to about half a minute."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner_client.build import build_controller
from planner_client.costs import TERMS, CostTerm, register
from planner_client.problem import build_problem, check_terms
from server.inprocess import build_episode
from shared import protocol as P
from shared.config import ConfigError, load_yaml
from shared.scenario import find_scenario, parse_scenario

FUZZ = settings(
    max_examples=120,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)
EDGES = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, 1e9, -1e9, 5e-324, -0.0, 0.0]


@pytest.fixture(scope="module")
def planner():
    """The navigation planner and the first states of its episode (a handshake's worth)."""
    controller = build_controller("navigation", threads=2)
    episode = build_episode(controller.motion.problem.scenario, seed=0)
    controller.begin("lockstep", episode.dt)
    states = [episode.publish()]
    for _ in range(3):
        episode.play(controller.step(states[-1]))
        states.append(episode.publish())
    yield controller, episode.dt, states
    controller.close()
    episode.close()


def _fields(state: P.State) -> list[tuple[str, int | None]]:
    out: list[tuple[str, int | None]] = [("time", None), ("lag", None)]
    for name in ("qpos", "qvel", "mocap_pos", "mocap_quat"):
        out += [(name, i) for i in range(np.asarray(getattr(state, name)).size)]
    return out


@FUZZ
@given(data=st.data(), mode=st.sampled_from(["lockstep", "realtime"]))
def test_a_state_at_the_edges_is_refused_or_answered_within_the_ranges(planner, data, mode):
    controller, dt, states = planner
    controller.begin(mode, dt)
    good = data.draw(st.sampled_from(states))
    name, i = data.draw(st.sampled_from(_fields(good)))
    value = data.draw(st.sampled_from(EDGES))
    if i is None:
        hostile = dataclasses.replace(good, **{name: value})
    else:
        array = np.array(getattr(good, name), dtype=float)
        array.flat[i] = value
        hostile = dataclasses.replace(good, **{name: array})
    try:
        state = P.decode(P.encode(hostile), expect="state", versions=P.VERSIONS)
    except P.ProtocolError:
        return  # refused at the door: counted by the loop, which answers the next state
    model = controller.motion.problem.model
    lo, hi = model.actuator_ctrlrange.T
    for s in (state, states[-1]):  # and the planner goes on with a good one
        cmd = controller.step(s)
        if cmd is None:
            continue
        ctrl = np.asarray(cmd.ctrl, dtype=float)
        assert np.isfinite(ctrl).all() and (lo <= ctrl).all() and (ctrl <= hi).all(), (name, i)
        assert np.isfinite(cmd.plan_t0) and np.isfinite(np.asarray(cmd.plan_ctrl)).all()


# ---------------------------------------------------------------- user terms

RETURNED: list = []  # what the fuzzed term returns next


@dataclasses.dataclass
class _Fuzzed(CostTerm):
    @classmethod
    def from_params(cls, s, ctx):
        return cls()

    def sensors(self):
        return []

    def __call__(self, batch):
        return RETURNED[0]


@pytest.fixture(scope="module")
def problem():
    """Navigation with one more term of the navigate objective: the fuzzed one."""
    register("fuzzed_return")(_Fuzzed)
    raw = copy.deepcopy(load_yaml(find_scenario("navigation")))
    raw["objectives"]["navigate"]["terms"].append({"term": "fuzzed_return", "weight": 1.0})
    RETURNED[:] = [torch.zeros(2, raw["planner"].get("horizon", 15), dtype=torch.float64)]
    yield build_problem(parse_scenario(raw, "fuzzed.yaml"))
    TERMS.pop("fuzzed_return")


_dims = st.lists(st.sampled_from([0, 1, 2, 3, 15, 16]), max_size=3)
returns = st.one_of(
    st.builds(
        lambda shape, dtype: torch.zeros(shape, dtype=dtype),
        _dims,
        st.sampled_from(
            [torch.float64, torch.float32, torch.float16, torch.int64, torch.bool, torch.complex128]
        ),
    ),
    st.builds(lambda shape: np.zeros(shape), _dims),
    st.floats(allow_nan=True),
    st.integers(),
    st.none(),
    st.text(max_size=5),
    st.lists(st.floats(), max_size=4),
    st.just(torch.zeros(2, 15, dtype=torch.float64)),
    st.just(torch.zeros(2, 15, dtype=torch.float64).T),
    st.just(torch.full((2, 15), math.nan, dtype=torch.float64)),
)


@FUZZ
@given(value=returns)
def test_a_term_returning_anything_passes_as_float64_s_by_t_or_is_named(problem, value):
    RETURNED[:] = [value]
    horizon = problem.scenario.planner.horizon
    try:
        check_terms(problem)
    except ConfigError as exc:
        assert "cost term 'fuzzed_return' of objective 'navigate'" in str(exc), str(exc)
        assert "fuzzed.yaml" in str(exc)
        return
    assert isinstance(value, torch.Tensor) and value.dtype == torch.float64
    assert tuple(value.shape) == (2, horizon)
