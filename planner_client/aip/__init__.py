"""Active-inference task planner (thesis Sec. 2.1.2, thesis Alg. 1; paper Sec. II.B, paper Alg. 2).

Build a planner from a parsed action template (:func:`shared.task_template.parse_task`) and call
:meth:`ActiveInferencePlanner.step` with one observation per factor every AIP tick.
"""

from planner_client.aip.agent import FactorAgent, FactorModel
from planner_client.aip.task_planner import ActiveInferencePlanner, Decision

__all__ = ["ActiveInferencePlanner", "Decision", "FactorAgent", "FactorModel"]
