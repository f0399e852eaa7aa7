"""What costs and observers read from rollouts, added to the rollout model as MuJoCo sensors.

Cost terms declare :class:`SensorRequest` s; :func:`add_sensors` adds each distinct request once
to the planner's ``MjSpec`` before compiling, and :class:`SensorColumns` maps a request to its
columns of ``sensordata``. Rollouts then return every needed quantity for all samples and steps in
one array ``[S, T, nsensordata]``, so costs are pure tensor maths with no per-sample Python.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import mujoco
import numpy as np
import torch

from shared.frames import FrameResolver

_KINDS: dict[str, tuple[int, int]] = {
    "framepos": (mujoco.mjtSensor.mjSENS_FRAMEPOS, 3),
    "framexaxis": (mujoco.mjtSensor.mjSENS_FRAMEXAXIS, 3),
    "frameyaxis": (mujoco.mjtSensor.mjSENS_FRAMEYAXIS, 3),
    "framezaxis": (mujoco.mjtSensor.mjSENS_FRAMEZAXIS, 3),
    "framelinvel": (mujoco.mjtSensor.mjSENS_FRAMELINVEL, 3),
    "distance": (mujoco.mjtSensor.mjSENS_GEOMDIST, 1),
    "contactforce": (mujoco.mjtSensor.mjSENS_CONTACT, 3),
    "jointpos": (mujoco.mjtSensor.mjSENS_JOINTPOS, 1),
    "jointvel": (mujoco.mjtSensor.mjSENS_JOINTVEL, 1),
}

# CONTACT sensor settings (intprm = data fields, reduction, slots): only the force field, all
# matching contacts summed into one net force ("netforce" is reduction 3), hence one slot of dim 3.
_CONTACT_INTPRM = (1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE), 3, 1)


class SensorRequest(NamedTuple):
    """One quantity per rollout step: ``kind`` of frame ``obj`` (YAML frame names).

    ``distance`` is the signed distance between the geoms of bodies ``obj`` and ``ref``, reported
    as ``cutoff`` when farther apart (MuJoCo's GEOMDIST sensor). ``contactforce`` is the net
    contact force [3] between the subtree of body ``obj`` (a robot with all its links) and the
    geoms of body ``ref`` (MuJoCo's CONTACT sensor, zero when they do not touch). ``jointpos``
    and ``jointvel`` are the position and velocity of the hinge or slide joint named ``obj`` (a
    joint name, not a frame). A frame quantity (``frame*``) with a ``ref`` is expressed in the
    frame ``ref`` instead of the world's.

    A named tuple, not a dataclass: terms look their requests up in :class:`SensorColumns`
    every iteration (pick_place 25 times), and a tuple's hash and equality run in C: 0.09 µs
    a lookup against a frozen dataclass's 0.54 µs, warm.
    """

    kind: str
    obj: str
    ref: str = ""
    cutoff: float = 0.0

    @property
    def name(self) -> str:
        tail = ""
        if self.kind == "distance":
            tail = f"__{self.ref}__{self.cutoff:g}"
        elif self.kind == "contactforce":
            tail = f"__{self.ref}"
        elif self.ref:
            tail = f"__in__{self.ref}"
        return f"m3p2i__{self.kind}__{self.obj}{tail}"

    @property
    def dim(self) -> int:
        return _KINDS[self.kind][1]


def add_sensors(spec: mujoco.MjSpec, requests: list[SensorRequest], resolve: FrameResolver) -> None:
    """Add each distinct request to ``spec`` (before compiling the rollout model)."""
    for req in dict.fromkeys(requests):
        stype, _ = _KINDS[req.kind]
        if req.kind in ("jointpos", "jointvel"):
            spec.add_sensor(
                name=req.name, type=stype, objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=req.obj
            )
            continue
        objtype, objname = resolve.mujoco_ref(req.obj)
        sensor = spec.add_sensor(name=req.name, type=stype, objtype=objtype, objname=objname)
        if req.kind == "distance":
            reftype, refname = resolve.mujoco_ref(req.ref)
            sensor.reftype, sensor.refname = reftype, refname
            sensor.cutoff = req.cutoff
        elif req.kind == "contactforce":
            sensor.objtype = mujoco.mjtObj.mjOBJ_XBODY  # XBODY selects the body's subtree
            sensor.reftype, sensor.refname = resolve.mujoco_ref(req.ref)
            sensor.intprm[:3] = _CONTACT_INTPRM
        elif req.ref:
            sensor.reftype, sensor.refname = resolve.mujoco_ref(req.ref)


class SensorColumns:
    """Columns of ``sensordata`` for each request (``spans``; :meth:`of_model` looks them up in
    a compiled model)."""

    def __init__(self, columns: dict[SensorRequest, slice]):
        self.spans = columns
        self._groups: dict[tuple[SensorRequest, ...], slice | torch.Tensor] = {}

    @classmethod
    def of_model(cls, model: mujoco.MjModel, requests: list[SensorRequest]) -> SensorColumns:
        columns = {}
        for req in dict.fromkeys(requests):
            s = model.sensor(req.name)
            columns[req] = slice(int(s.adr[0]), int(s.adr[0]) + int(s.dim[0]))
        return cls(columns)

    def take(self, sensordata: torch.Tensor, req: SensorRequest) -> torch.Tensor:
        """``sensordata [..., nsensordata]`` -> ``[..., dim]`` for one request."""
        return sensordata[..., self.spans[req]]

    def take_all(self, sensordata: torch.Tensor, reqs: list[SensorRequest]) -> torch.Tensor:
        """``[..., Σ dim]`` for several requests: a view when their columns are adjacent (as
        :func:`add_sensors` lays out one term's requests), else a copy of the columns in
        request order. Where they are is worked out once per list of requests."""
        key = tuple(reqs)
        cols = self._groups.get(key)
        if cols is None or (isinstance(cols, torch.Tensor) and cols.device != sensordata.device):
            cols = self._groups[key] = self._columns_of(key, sensordata.device)
        if isinstance(cols, slice):
            return sensordata[..., cols]
        return sensordata.index_select(-1, cols)

    def _columns_of(
        self, reqs: tuple[SensorRequest, ...], device: torch.device
    ) -> slice | torch.Tensor:
        spans = [self.spans[r] for r in reqs]
        if all(a.stop == b.start for a, b in itertools.pairwise(spans)):
            return slice(spans[0].start, spans[-1].stop)
        return torch.tensor(
            [i for span in spans for i in range(span.start, span.stop)],
            dtype=torch.long,
            device=device,
        )


class SensorSwitch:
    """Which of a model's sensors MuJoCo computes.

    The planner's model carries the sensors of every objective (pick_place's 30, of which its
    'reach' reads 20), and MuJoCo computes every sensor of a model at every step of every
    rollout: a distance sensor runs a collision query, a contact sensor scans the contacts
    (together 4-5 % of pick_place's and mobile_pick_place's rollouts). :meth:`only` makes the
    sensors not read into clock sensors (one number copied at the position stage) and the read
    ones what they were. Sensors never act on the physics, so the rollouts and the columns read
    are the same bit for bit; the columns of a switched sensor hold meaningless finite numbers.
    """

    def __init__(self, model: mujoco.MjModel):
        """Remembers ``model``'s sensors as compiled: every one computed."""
        self._type = model.sensor_type.copy()
        self._stage = model.sensor_needstage.copy()

    def only(self, models: list[mujoco.MjModel], read: np.ndarray | None) -> None:
        """Compute in each of ``models`` (the compiled model or its copies) only the sensors
        ``read`` (ids); None: every sensor."""
        off = np.ones(self._type.shape, dtype=bool)
        off[slice(None) if read is None else read] = False
        kind = np.where(off, int(mujoco.mjtSensor.mjSENS_CLOCK), self._type)
        stage = np.where(off, int(mujoco.mjtStage.mjSTAGE_POS), self._stage)
        for m in models:
            m.sensor_type[:] = kind
            m.sensor_needstage[:] = stage
