"""Cost terms (a registry YAML names them by) and objectives (weighted sums of terms).

Terms live by concept: ``poses`` (distances, orientation, approach), ``contact`` (obstacles),
``clearance``, ``perceived`` (obstacles of the planner's map), ``path`` (the guide's),
``push_pull``, ``gripper``, ``control``, ``joints`` (limits, posture); what several of them
use is public in ``helpers``.
"""

# importing the term modules registers their terms
from planner_client.costs import (  # noqa: F401
    clearance,
    contact,
    control,
    gripper,
    joints,
    path,
    perceived,
    poses,
    push_pull,
)
from planner_client.costs.base import (
    TERMS,
    CostTerm,
    JointInfo,
    RolloutBatch,
    TermContext,
    register,
)
from planner_client.costs.objective import Objective, build_objective

__all__ = [
    "TERMS",
    "CostTerm",
    "JointInfo",
    "Objective",
    "RolloutBatch",
    "TermContext",
    "build_objective",
    "register",
]
