"""Cost terms (a registry YAML names them by) and objectives (weighted sums of terms)."""

from planner_client.costs.base import TERMS, CostTerm, JointInfo, RolloutBatch, TermContext, register
from planner_client.costs.objective import Objective, build_objective
from planner_client.costs import terms as _terms  # noqa: F401  (registers the built-in terms)
from planner_client.costs import manipulation as _manipulation  # noqa: F401  (Sec. III.A terms)
from planner_client.costs import joints as _joints  # noqa: F401  (joint limits, posture)

__all__ = ["TERMS", "CostTerm", "JointInfo", "Objective", "RolloutBatch", "TermContext", "build_objective",
           "register"]
