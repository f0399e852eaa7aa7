"""How close the robot came to the objects only its sensors show (``world.objects[].perceived``).

Two figures per episode, from its log: ``perceived_contacts``, the contact onsets between the
robot or a free object it may carry (every collidable geom of the robot's tree and of the free
objects the planner knows) and a perceived object's geom; and ``perceived_clearance_min``, the
smallest signed distance between such a pair over the episode (m; negative: penetration),
MuJoCo's ``mj_geomDistance`` at every logged step. Distances beyond :data:`DIST_MAX` are not
computed: a clearance of ``DIST_MAX`` means "at least that". A step touches when its smallest
distance is at most 0, whatever contacts MuJoCo's filters would generate (a mocap body and the
Panda's base, both static, make none).
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.scenario import Scenario

DIST_MAX = 1.0  # m: farther pairs are not measured, and the clearance says "at least 1 m"


class PerceivedClearance:
    """The geom pairs of a scenario's world model that :func:`clearance` measures: the robot's
    and its known free objects' collidable geoms ``[A]`` against the perceived objects' ``[B]``.
    """

    def __init__(self, scenario: Scenario, model: mujoco.MjModel, robot: np.ndarray):
        """``robot``: which geoms ``[ngeom]`` belong to the robot's kinematic tree."""
        objects = scenario.world.objects
        free = [model.body(o.name).id for o in objects if not (o.fixed or o.perceived)]
        perceived = [model.body(o.name).id for o in objects if o.perceived]
        collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        self.model = model
        self.a = np.flatnonzero(collides & (robot | np.isin(model.geom_bodyid, free)))
        self.b = np.flatnonzero(collides & np.isin(model.geom_bodyid, perceived))
        self._reach = model.geom_rbound[self.a][:, None] + model.geom_rbound[self.b][None, :]

    def clearance(self, data: mujoco.MjData) -> float:
        """The smallest signed distance (m) between a pair in ``data`` (kinematics computed),
        at most :data:`DIST_MAX`. Pairs whose bounding spheres are farther apart than that are
        skipped: their distance is larger."""
        centres = data.geom_xpos[self.a][:, None, :] - data.geom_xpos[self.b][None, :, :]
        gap = np.linalg.norm(centres, axis=-1) - self._reach  # [A, B], a lower bound
        best = DIST_MAX
        for i, j in zip(*np.nonzero(gap < DIST_MAX)):
            d = mujoco.mj_geomDistance(self.model, data, self.a[i], self.b[j], DIST_MAX, None)
            best = min(best, d)
        return float(best)
