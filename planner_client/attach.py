"""Grasped objects welded to the robot in the planner's model (``planner.model.attach``).

A cube held between two rubber pads is, for the constraint solver, eight or more elliptic
friction contacts squeezed by 70 N: most of a carrying rollout step's cost (docs/panda.md), so a
planner that is slower than its world falls furthest behind exactly while it carries. While the
task observes the attachment's state (``holding``), the planner's model instead welds the object
to the robot body at their relative pose of the moment (one 6-row equality) and drops the
object's contacts with the robot; its contacts with everything else stay. The world keeps the
real grasp, so a cube that slips in the world is seen in the next state, and once the task
observes it lost (within ``aip_period`` plus ``planner.confirm``) it is released here too.

How the contacts are dropped without recompiling: one contact bit that no geom of the scene uses
is added to every colliding geom outside the robot (not to a visual marker, which collides with
nothing); an attached object's geoms carry that bit alone, so they still meet the table and the
other objects (bit shared) but never the robot (bit absent, and the object no longer has the
robot's bits). The weld is activated through ``eq_active0``,
because ``mujoco.rollout`` starts every rollout from a reset MjData, whose equality flags are
the model's, and through the mirror's ``eq_active`` for the prediction over the plan's lead.

A held object's measured pose carries perception's noise, while the hand's comes from the arm's
encoders: with ``planner.tracking.held_filter`` < 1, :meth:`Attachments.track` puts each attached
object where the hand holds it, at a relative pose filtered over the states (constant while the
grasp holds, so a strong filter costs no lag) and moving with the hand. A relative pose that
jumps by more than ``slip`` is taken as measured (a cube slipped or was taken). The relative pose
is measured from the pose as received, not the mirror's filtered one: that filter trails a
carried cube by its speed × the state period × (1 − w)/w, 12 cm at 0.65 m/s and 30 states a
second, which the slip test took for a slip (pick_place_lab in real time, 4 of 20 hands opened
in mid-air).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import mujoco
import numpy as np

from shared.scenario import Attach

log = logging.getLogger("m3p2i.planner")

EQUALITY_PREFIX = "m3p2i_attach_"


def add_attach_welds(spec: mujoco.MjSpec, attach: tuple[Attach, ...]) -> None:
    """One inactive weld per attachment (``m3p2i_attach_<object>``), its pose set at run time.
    Raises KeyError naming a body the spec lacks (the caller turns it into a ConfigError)."""
    bodies = {b.name for b in spec.bodies}
    for i, a in enumerate(attach):
        for key, name in (("object", a.object), ("to", a.to)):
            if name not in bodies:
                raise KeyError((i, key, name, sorted(bodies)))
        spec.add_equality(
            name=EQUALITY_PREFIX + a.object,
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1=a.object,
            name2=a.to,
            active=False,
            data=np.zeros(mujoco.mjNEQDATA),
        )


@dataclass
class _Weld:
    cfg: Attach
    eq: int  # equality id
    body: int  # the object's body
    to: int  # the robot body it is welded to
    geoms: np.ndarray  # [G] the object's geoms
    on: bool = False
    rel: np.ndarray | None = None  # [7] filtered pose in ``to``'s frame, while on and tracked


class Attachments:
    """Switches each attachment on and off in ``model`` (the planner's own, shared with its
    rollouts) from the task's observation."""

    def __init__(
        self,
        model: mujoco.MjModel,
        attach: tuple[Attach, ...],
        held_filter: float = 1.0,
        slip: float = 0.02,
    ):
        self.model = model
        self.held_filter = held_filter
        self.slip = slip
        self.welds: list[_Weld] = []
        if not attach:
            return
        used = int(
            np.bitwise_or.reduce(np.concatenate([model.geom_contype, model.geom_conaffinity]))
        )
        free = [1 << k for k in range(31) if not used & (1 << k)]
        if not free:
            raise ValueError(
                "planner.model.attach needs one contact bit that no geom uses; "
                "every one of the 31 is taken"
            )
        self.bit = free[0]
        robots = set()
        for a in attach:
            body, to = model.body(a.object).id, model.body(a.to).id
            robots.add(int(model.body_rootid[to]))
            geoms = np.flatnonzero(model.body_rootid[model.geom_bodyid] == body)
            self.welds.append(
                _Weld(a, model.equality(EQUALITY_PREFIX + a.object).id, body, to, geoms)
            )
        # only geoms that collide: a visual marker (both masks 0) given the bit would meet the
        # table, the objects and a carried cube in every rollout
        collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        outside = ~np.isin(model.body_rootid[model.geom_bodyid], list(robots)) & collides
        model.geom_contype[outside] |= self.bit
        model.geom_conaffinity[outside] |= self.bit
        self._bit_of = np.where(collides, self.bit, 0).astype(model.geom_contype.dtype)
        self._contype = model.geom_contype.copy()  # each geom's bits when detached
        self._conaffinity = model.geom_conaffinity.copy()

    def track(self, data: mujoco.MjData, received_qpos: np.ndarray | None = None) -> bool:
        """Each object welded since the last observation put where ``to`` holds it in ``data``
        (a new state, kinematics computed): pose ``to`` ∘ relative pose, filtered with weight
        ``held_filter``; velocity that of ``to`` at the object's origin. The object is measured
        in ``received_qpos [nq]`` (the state as received, before the mirror's filters) when
        given, else in ``data``. Returns whether ``data`` changed (the caller recomputes its
        kinematics and rollout start)."""
        if self.held_filter >= 1.0:
            return False
        m, w, changed = self.model, self.held_filter, False
        for weld in self.welds:
            if not weld.on or weld.rel is None:
                continue
            measured = (
                relative_pose(data, weld.body, weld.to)
                if received_qpos is None
                else _received_relative_pose(m, data, received_qpos, weld.body, weld.to)
            )
            if np.linalg.norm(measured[:3] - weld.rel[:3]) > self.slip:
                weld.rel = measured
            else:
                q = measured[3:] * (1.0 if measured[3:] @ weld.rel[3:] >= 0 else -1.0)
                weld.rel[:3] = w * measured[:3] + (1 - w) * weld.rel[:3]
                blended = w * q + (1 - w) * weld.rel[3:]
                weld.rel[3:] = blended / np.linalg.norm(blended)
            _hold_at(m, data, weld.body, weld.to, weld.rel)
            changed = True
        return changed

    def update(self, data: mujoco.MjData, observation: dict[str, str], time: float) -> None:
        """Attach what the observation says is held, at its pose in ``data`` (the mirrored
        state, kinematics computed); release the rest. ``data`` gets the same equality flags,
        so that the prediction over the plan's lead uses the same model as the rollouts."""
        held = set(observation.values())
        m = self.model
        for w in self.welds:
            on = w.cfg.state in held
            if on:
                # MuJoCo's weld holds x2 + R2·anchor at x1 + R1·relpos. The anchor is the object's
                # origin (in the robot body's frame) and relpos 0: anchored at the hand's origin,
                # 11 cm away, the soft weld let a cube held off the hand's axis swing down like a
                # pendulum (7.8 mm in 0.2 s with the arm still; tests/planner_client/test_attach.py)
                m.eq_data[w.eq, :3] = relative_pose(data, w.body, w.to)[:3]
                m.eq_data[w.eq, 3:6] = 0.0
                m.eq_data[w.eq, 6:10] = relative_pose(data, w.to, w.body)[3:]
                m.eq_data[w.eq, 10] = 1.0  # torque scale
            if on != w.on:
                log.info(
                    "t=%.2f s: %s %s %s in the planner's model",
                    time,
                    w.cfg.object,
                    "welded to" if on else "released from",
                    w.cfg.to,
                )
                if on:
                    m.geom_contype[w.geoms] = self._bit_of[w.geoms]
                    m.geom_conaffinity[w.geoms] = self._bit_of[w.geoms]
                else:
                    m.geom_contype[w.geoms] = self._contype[w.geoms]
                    m.geom_conaffinity[w.geoms] = self._conaffinity[w.geoms]
                w.on = on
                w.rel = relative_pose(data, w.body, w.to) if on else None
            m.eq_active0[w.eq] = on
            data.eq_active[w.eq] = on

    @property
    def attached(self) -> tuple[str, ...]:
        """The objects welded now."""
        return tuple(w.cfg.object for w in self.welds if w.on)


def _hold_at(
    model: mujoco.MjModel, data: mujoco.MjData, body: int, to: int, rel: np.ndarray
) -> None:
    """Set free ``body``'s ``qpos`` to ``to``'s pose composed with ``rel`` ``[7]`` and its
    ``qvel`` to ``to``'s rigid motion there (linear in the world frame, angular in the body's:
    the free joint's convention)."""
    qadr = model.jnt_qposadr[model.body_jntadr[body]]
    vadr = model.jnt_dofadr[model.body_jntadr[body]]
    pos, quat = np.zeros(3), np.zeros(4)
    mujoco.mju_rotVecQuat(pos, rel[:3], data.xquat[to])
    pos += data.xpos[to]
    mujoco.mju_mulQuat(quat, data.xquat[to], rel[3:])
    data.qpos[qadr : qadr + 3], data.qpos[qadr + 3 : qadr + 7] = pos, quat
    vel = np.zeros(6)  # [angular, linear] at to's origin, world
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_XBODY, to, vel, 0)
    linear = vel[3:] + np.cross(vel[:3], pos - data.xpos[to])
    angular = np.zeros(3)
    inv = np.zeros(4)
    mujoco.mju_negQuat(inv, quat)
    mujoco.mju_rotVecQuat(angular, vel[:3], inv)
    data.qvel[vadr : vadr + 3], data.qvel[vadr + 3 : vadr + 6] = linear, angular


def _received_relative_pose(
    model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, body: int, frame: int
) -> np.ndarray:
    """``[7]``: free ``body``'s pose in ``qpos [nq]`` (a free joint's qpos is its body's world
    pose) in the frame of body ``frame`` as ``data`` has it."""
    qadr = model.jnt_qposadr[model.body_jntadr[body]]
    quat = qpos[qadr + 3 : qadr + 7]
    norm = np.linalg.norm(quat)
    if not norm > 0:  # no orientation received (a bridge's zeros): the mirrored one
        return relative_pose(data, body, frame)
    return _in_frame(data, frame, qpos[qadr : qadr + 3], quat / norm)


def relative_pose(data: mujoco.MjData, body: int, frame: int) -> np.ndarray:
    """``[7]``: position and quaternion of ``body`` in the frame of body ``frame`` (MuJoCo's
    weld ``relpose``: body2's pose in body1's frame)."""
    return _in_frame(data, frame, data.xpos[body], data.xquat[body])


def _in_frame(data: mujoco.MjData, frame: int, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """``[7]``: the world pose ``pos [3]``, ``quat [4]`` in the frame of body ``frame``."""
    inv = np.zeros(4)
    mujoco.mju_negQuat(inv, data.xquat[frame])
    rel_pos, rel_quat = np.zeros(3), np.zeros(4)
    mujoco.mju_rotVecQuat(rel_pos, pos - data.xpos[frame], inv)
    mujoco.mju_mulQuat(rel_quat, inv, quat)
    return np.concatenate([rel_pos, rel_quat])
