"""Assemble a planner from a scenario: problem, motion planner, task layer, controller, client."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path

import torch

from planner_client.aip import ActiveInferencePlanner
from planner_client.attach import Attachments
from planner_client.backends import make_backend
from planner_client.controller import Controller, Parts
from planner_client.guide import Guide
from planner_client.loop import PlannerClient
from planner_client.maps import build_map, map_sensors
from planner_client.mirror import Mirror
from planner_client.motion import MotionPlanner
from planner_client.observers import SymbolicObserver
from planner_client.problem import build_problem, check_terms, mppi_config
from planner_client.task import ActiveInferenceTask, FixedModes, TaskLayer
from planner_client.variants import Identifier, VariantModels
from shared.config import ConfigError
from shared.endpoints import Endpoints
from shared.predicates import check_frames
from shared.scenario import Scenario, load_scenario


def build_motion_planner(
    scenario: Scenario,
    threads: int = 0,
    seed: int | None = None,
    backend: str | None = None,
    device: str | None = None,
) -> MotionPlanner:
    """The scenario's motion planner; ``backend`` and ``device`` override ``planner.backend``
    and ``planner.device`` (the warp backend checks the model against MJWarp's limits here)."""
    # The planner's tensors are small ([S, T, ·] with S·T ~ 3000): torch's intra-op threads gain
    # nothing there, and their spinning steals the cores mujoco.rollout's pool needs (measured:
    # 12.5 ms -> 7.6 ms per navigation iteration on 2 cores).
    torch.set_num_threads(1)
    problem = build_problem(scenario)
    modes = list(scenario.modes) or [next(iter(scenario.action_objectives.values()))]
    cfg = mppi_config(scenario, problem.model)
    if seed is not None:
        cfg = dataclasses.replace(cfg, seed=seed)
    pc = scenario.planner
    nthread = threads or pc.threads
    engine = None
    variants = None
    if pc.model.variants is not None:
        if (backend or pc.backend) != "mujoco":
            raise ConfigError(
                scenario.source,
                "planner.model.variants",
                f"the {backend or pc.backend} backend rolls out one model for all samples",
                expected="--backend mujoco (mujoco.rollout takes a model per rollout), "
                "or a scenario without variants",
            )
        # the objects of the planner's model: its perceived ones are not there
        variants = VariantModels(problem.model, problem.scenario.world.objects, pc.model.variants)
    if (backend or pc.backend) != "mujoco":
        # every mode rolls out planner.samples: the worlds are allocated for all of them now
        engine = make_backend(
            backend or pc.backend,
            problem.model,
            samples=len(modes) * pc.samples,
            horizon=pc.horizon,
            nthread=nthread,
            device=device or pc.device,
            nconmax=pc.nconmax,
            njmax=pc.njmax,
            source=scenario.source,
        )
    # a term that returns the wrong thing stops the planner here, named, before it connects
    check_terms(problem, engine.device if engine is not None else "cpu")
    return MotionPlanner(
        problem, cfg, pc.samples, modes, nthread=nthread, backend=engine, variants=variants
    )


def build_task(scenario: Scenario, motion: MotionPlanner) -> TaskLayer:
    """Fixed modes, or active inference when the scenario has a task template."""
    if scenario.task is None:
        return FixedModes(scenario.modes)
    problem = motion.problem
    for factor, cfg in scenario.observers.items():
        for _, pred in cfg.rules:
            check_frames(pred, problem.resolve, scenario.source, f"observers.{factor}")
    return ActiveInferenceTask(
        ActiveInferencePlanner(scenario.task, waits=bool(scenario.team)),
        SymbolicObserver(scenario.observers, problem.resolve),
        scenario.action_objectives,
        scenario.planner.aip_period,
        scenario.planner.confirm,
    )


def build_parts(motion: MotionPlanner, task: TaskLayer) -> Parts:
    """The collaborators a :class:`Controller` drives for ``motion`` and ``task``: the mirror
    (with ``planner.tracking``'s filters), the attachments of ``planner.model.attach``, the
    guide of ``guide``, the maker of the map of the scenario's sensors (:mod:`planner_client.maps`)
    and, with ``planner.model.variants.identify``, the maker of the identifier that reweights
    the motion planner's variants."""
    problem = motion.problem
    pc = problem.scenario.planner
    mirror = Mirror(
        problem.model,
        tracking=pc.tracking,
        planar=[n for n, o in pc.model.objects.items() if o.planar],
    )
    attachments = Attachments(problem.model, pc.model.attach, held_filter=pc.tracking.held_filter)
    guide = None
    if problem.guide is not None:  # it plans on the planner's map too, once there is one
        guide = Guide(problem.guide, problem.model, problem.resolve, problem.field_source)
    parts = Parts(motion, task, mirror, attachments, guide)
    # map_sensors reads planner.map: a faulty one stops the planner here, not later
    if map_sensors(problem.scenario):
        # made at Controller.begin: whether it runs a thread depends on the world's mode
        parts.map = functools.partial(build_map, problem)
    variants = motion.variants
    if variants is not None and variants.cfg.identify is not None:
        estimator = mirror.estimator
        from_poses = bool(estimator and estimator.cfg.object_velocities == "from_poses")
        parts.identifier = lambda dt: Identifier(variants, dt, from_poses=from_poses)
    return parts


def build_controller(
    scenario: Scenario | str | Path,
    threads: int = 0,
    seed: int | None = None,
    backend: str | None = None,
    device: str | None = None,
) -> Controller:
    """The control loop of ``scenario`` (a loaded scenario, a name or a YAML path; thesis
    Alg. 1): its motion planner and task layer as ``m3p2i-planner`` builds them, without
    sockets, sampling with ``seed`` (None: ``planner.mppi.seed``); a new episode with a seed
    rebuilds both, sampling with that seed. Call :meth:`Controller.begin` before the first
    step."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)

    def renew(episode_seed: int | None):
        motion = build_motion_planner(
            scenario, threads, seed if episode_seed is None else episode_seed, backend, device
        )
        return build_parts(motion, build_task(scenario, motion))

    return Controller(renew(None), renew=renew)


def build_client(
    scenario: Scenario,
    endpoints: Endpoints,
    threads: int = 0,
    seed: int | None = None,
    backend: str | None = None,
    device: str | None = None,
    before_connect: Callable[[], None] | None = None,
    **options,
) -> PlannerClient:
    """The planner client of ``scenario``; ``before_connect`` runs once the planner and task
    are built (the slow part: imports, model compilation) and before any socket is opened:
    a hot spare waits there."""
    controller = build_controller(scenario, threads, seed, backend, device)
    if before_connect is not None:
        before_connect()
    if scenario.team:  # a team robot's planner: its robot's name and place in the team
        names = [m.name for m in scenario.team]
        options.update(robot=scenario.member, robot_index=names.index(scenario.member))
    return PlannerClient(controller, endpoints, scenario.name, scenario.hash, **options)
