"""``planner.tracking``: how the planner's mirror reads bodies a world measures by perception."""

from __future__ import annotations

from dataclasses import dataclass

from shared.config import (
    Section,
    flag,
    non_negative,
    one_of,
    positive,
)
from shared.scenario.common import unit_weight


@dataclass(frozen=True)
class TrackingConfig:
    """``planner.tracking``: how the planner's mirror turns received states of the free bodies
    (the scenario's objects) into the rollouts' start, for worlds whose object poses come from
    perception (noisy) and whose object velocities are not measured."""

    object_velocities: str = "received"  # received | from_poses (finite differences)
    pose_filter: float = 1.0  # weight of a new pose in an exponential filter; 1: none
    velocity_filter: float = 1.0  # weight of a new finite-difference velocity; 1: none
    max_speed: float = 5.0  # m/s: a faster jump is a teleport (filters restart)
    held_filter: float = 1.0  # weight of a new relative pose of an attached object
    still_speed: float = 0.0  # m/s: a slower filtered velocity is noise, taken as 0
    predict: bool = False  # blend a new pose with the last one moved on by its velocity


def read_tracking(s: Section) -> TrackingConfig:
    cfg = TrackingConfig(
        object_velocities=s.opt(
            "object_velocities", "received", one_of(("received", "from_poses"))
        ),
        pose_filter=s.opt("pose_filter", 1.0, unit_weight, "a weight in (0, 1]"),
        velocity_filter=s.opt("velocity_filter", 1.0, unit_weight, "a weight in (0, 1]"),
        max_speed=s.opt("max_speed", 5.0, positive, "m/s > 0"),
        held_filter=s.opt("held_filter", 1.0, unit_weight, "a weight in (0, 1]"),
        still_speed=s.opt("still_speed", 0.0, non_negative, "m/s >= 0"),
        predict=s.opt("predict", False, flag, "true or false"),
    )
    s.done()
    return cfg
