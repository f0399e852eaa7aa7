"""Sampling-based motion planning: MPPI (thesis Alg. 2) and M3P2I (paper Alg. 3-4).

Pure torch, no simulator: the planners hand out control sequences ``[S, T, nu]`` and take back
per-step costs ``[S, T]``. See docs/mppi.md for the equations and parameters.
"""

from .config import ModeSpec, MPPIConfig
from .m3p2i import M3P2I
from .mppi import MPPI
from .result import PlanResult

__all__ = ["M3P2I", "MPPI", "MPPIConfig", "ModeSpec", "PlanResult"]
