"""Assemble a planner client from a scenario: problem, motion planner, task layer, loop."""

from __future__ import annotations

import torch

from shared.endpoints import Endpoints
from shared.scenario import Scenario
from planner_client.loop import PlannerClient
from planner_client.motion import MotionPlanner
from planner_client.problem import build_problem, mppi_config
from planner_client.task import FixedModes


def build_motion_planner(scenario: Scenario, threads: int = 0) -> MotionPlanner:
    # The planner's tensors are small ([S, T, ·] with S·T ~ 3000): torch's intra-op threads gain
    # nothing there, and their spinning steals the cores mujoco.rollout's pool needs (measured:
    # 12.5 ms -> 7.6 ms per navigation iteration on 2 cores).
    torch.set_num_threads(1)
    problem = build_problem(scenario)
    return MotionPlanner(problem, mppi_config(problem), scenario.planner.samples,
                         list(scenario.modes), nthread=threads or scenario.planner.threads)


def build_client(scenario: Scenario, endpoints: Endpoints, threads: int = 0,
                 **options) -> PlannerClient:
    planner = build_motion_planner(scenario, threads)
    task = FixedModes(scenario.modes)
    return PlannerClient(planner, task, endpoints, scenario.name, scenario.hash, **options)
