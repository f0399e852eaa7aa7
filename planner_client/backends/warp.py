"""The MuJoCo Warp rollout backend: all samples stepped together, one Warp "world" each.

MJWarp (``mujoco_warp``, the ``m3p2i[gpu]`` extra) runs MuJoCo's pipeline as Warp kernels on an
NVIDIA GPU, or on the CPU device (slowly: it exists there for tests). Per rollout the initial
state is broadcast to all worlds, then each of the T steps copies that step's controls (and
mocap poses) into the worlds, steps them, and copies their sensordata into a ``[T, S, ·]``
buffer; on a CUDA device those T steps are captured once as a CUDA graph and replayed. Warp
arrays and torch tensors share memory (``wp.to_torch``), so the returned sensordata stays on
the device and the costs and the M3P2I update run there.

MJWarp computes in float32 (MuJoCo in float64): sensor trajectories agree with
``mujoco.rollout`` to float32 rounding on smooth motion and drift further where contacts decide
the motion (tests/planner_client/test_warp_backend.py states the tolerances).

Kernels are compiled on first use (LLVM on the CPU device, NVRTC on a GPU) and cached in
``~/.cache/warp``: the first rollout of a new model takes tens of seconds to minutes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from planner_client.backends.warp_limits import buffer_sizes, check_warp
from shared.config import ConfigError

log = logging.getLogger("m3p2i.planner")


def import_warp(source: str = ""):
    """``(warp, mujoco_warp)``, or a :class:`ConfigError` saying to install m3p2i[gpu]."""
    try:
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as exc:
        raise ConfigError(
            source,
            "planner.backend",
            f"the warp backend needs the m3p2i[gpu] extra ({exc.name} is missing): "
            "pip install -e '.[gpu]' in a clone",
            "warp",
            "planner.backend: mujoco, or install m3p2i[gpu]",
        ) from None
    return wp, mjw


@dataclass
class _Worlds:
    """MJWarp data for S worlds and the per-step buffers of one (S, T), as Warp arrays and
    torch views of the same memory."""

    data: object  # mujoco_warp.Data
    ctrl_seq: object  # wp.array [T, S, nu]
    mocap_seq: object | None  # wp.array [T, S, nmocap] of vec3
    out: object  # wp.array [T, S, nsensordata]
    ctrl_seq_t: torch.Tensor
    mocap_seq_t: torch.Tensor | None
    out_t: torch.Tensor
    sensordata: torch.Tensor  # [S, T, nsensordata] float64, what sensors() returns
    graphs: dict  # with/without a mocap path -> captured CUDA graph


class WarpBackend:
    """MJWarp rollouts of ``model`` on ``device`` (``cpu``, ``cuda``, ``cuda:N``).

    At construction the model is checked against MJWarp's limits (:func:`check_warp`) and put on
    the device; worlds and buffers are allocated per (samples, horizon) on first use, with
    ``nconmax`` contacts and ``njmax`` constraint rows per world (:func:`buffer_sizes`).
    Samples whose worlds overflow those buffers get NaN sensordata (hence no weight) and a
    warning naming the key to raise.
    """

    name = "warp"

    def __init__(
        self,
        model: mujoco.MjModel,
        *,
        samples: int = 0,
        horizon: int = 0,
        device: str = "cuda:0",
        nconmax: int | None = None,
        njmax: int | None = None,
        source: str = "",
    ):
        wp, mjw = import_warp(source)
        self._wp, self._mjw = wp, mjw
        check_warp(model, source)
        try:
            self.wp_device = wp.get_device(device)
        except (RuntimeError, ValueError):
            have = ", ".join(d.alias for d in wp.get_devices())
            raise ConfigError(
                source,
                "planner.device",
                "Warp has no such device (planner.device, or --device)",
                device,
                f"one of: {have}",
            ) from None
        self.device = torch.device(wp.device_to_torch(self.wp_device))
        self.model = model
        self.nconmax, self.njmax = buffer_sizes(model, nconmax, njmax)
        with wp.ScopedDevice(self.wp_device):
            try:
                self.wmodel = mjw.put_model(model)
            except (NotImplementedError, ValueError) as exc:  # a limit check_warp missed
                raise ConfigError(
                    source,
                    "planner.backend",
                    f"MuJoCo Warp cannot roll out this scenario's model: {exc}",
                    "warp",
                    "planner.backend: mujoco",
                ) from None
        self._capacity = int(
            sum(
                int(f)
                for f in mjw.OverflowType
                if f.name not in ("NONE", "ALL", "ITERATIONS", "LS_ITERATIONS")
            )
        )
        self._warned: set[str] = set()
        self._compiled = False  # CUDA: kernels are compiled by an uncaptured first run
        self._worlds: dict[tuple[int, int], _Worlds] = {}
        bodies = np.flatnonzero(model.body_mocapid >= 0)
        order = bodies[np.argsort(model.body_mocapid[bodies])]
        self._mocap_pos = torch.tensor(model.body_pos[order], dtype=torch.float32)
        self._mocap_quat = torch.tensor(model.body_quat[order], dtype=torch.float32)
        self._sizes = [
            mujoco.mj_stateSize(model, getattr(mujoco.mjtState, f"mjSTATE_{p}"))
            for p in ("TIME", "QPOS", "QVEL", "ACT")
        ]
        if samples and horizon:
            self._get_worlds(samples, horizon)

    # -- buffers -----------------------------------------------------------------------------

    def _get_worlds(self, samples: int, horizon: int) -> _Worlds:
        """The worlds for (samples, horizon); a new sample count (M3P2I's modes changed) gets
        its own, kept for when it comes back."""
        key = (samples, horizon)
        if key in self._worlds:
            return self._worlds[key]
        wp, m = self._wp, self.model
        with wp.ScopedDevice(self.wp_device):
            data = self._mjw.make_data(m, nworld=samples, nconmax=self.nconmax, njmax=self.njmax)
            ctrl_seq = wp.zeros((horizon, samples, m.nu), dtype=float)
            mocap_seq = wp.zeros((horizon, samples, m.nmocap), dtype=wp.vec3) if m.nmocap else None
            out = wp.zeros((horizon, samples, m.nsensordata), dtype=float)
        worlds = _Worlds(
            data=data,
            ctrl_seq=ctrl_seq,
            mocap_seq=mocap_seq,
            out=out,
            ctrl_seq_t=wp.to_torch(ctrl_seq),
            mocap_seq_t=None if mocap_seq is None else wp.to_torch(mocap_seq),
            out_t=wp.to_torch(out),
            sensordata=torch.empty(
                samples, horizon, m.nsensordata, dtype=torch.float64, device=self.device
            ),
            graphs={},
        )
        self._worlds[key] = worlds
        return worlds

    def set_mocap(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Mocap poses ``[nmocap, 3]``, ``[nmocap, 4]`` every rollout starts from."""
        self._mocap_pos = torch.as_tensor(pos, dtype=torch.float32)
        self._mocap_quat = torch.as_tensor(quat, dtype=torch.float32)

    def read_sensors(self, read: np.ndarray | None) -> None:
        """Every sensor stays computed: the model is on the device as put at construction, and
        its sensors run in parallel there."""

    # -- rollouts ----------------------------------------------------------------------------

    def _start(self, w: _Worlds, x0: np.ndarray) -> None:
        """Every world at ``x0`` (mjSTATE_FULLPHYSICS), as mujoco.rollout starts each rollout
        from a reset MjData: no warm start, no applied forces, the mocap poses of set_mocap."""
        wp, d = self._wp, w.data
        x = torch.as_tensor(np.asarray(x0, dtype=np.float32)).to(self.device)
        parts = torch.split(x, self._sizes)
        wp.to_torch(d.time).fill_(float(x0[0]))
        for field, part in zip(("qpos", "qvel", "act"), parts[1:]):
            if part.numel():
                wp.to_torch(getattr(d, field)).copy_(part.expand(d.nworld, -1))
        wp.to_torch(d.qacc_warmstart).zero_()
        wp.to_torch(d.overflow).zero_()
        if self.model.nmocap:
            wp.to_torch(d.mocap_pos).copy_(self._mocap_pos.to(self.device).expand(d.nworld, -1, -1))
            wp.to_torch(d.mocap_quat).copy_(
                self._mocap_quat.to(self.device).expand(d.nworld, -1, -1)
            )

    def _steps(self, w: _Worlds, horizon: int, with_path: bool) -> None:
        wp, d = self._wp, w.data
        for t in range(horizon):
            wp.copy(d.ctrl, w.ctrl_seq[t])
            if with_path:
                wp.copy(d.mocap_pos, w.mocap_seq[t])
            self._mjw.step(self.wmodel, d)
            wp.copy(w.out[t], d.sensordata)

    def sensors(
        self, x0: np.ndarray, control: torch.Tensor, mocap_path: np.ndarray | None = None
    ) -> torch.Tensor:
        """``sensordata [S, T, nsensordata]`` (float64, on this backend's device) of
        ``control [S, T, nu]`` rolled out from ``x0``; with ``mocap_path [T, nmocap, 3]`` the
        mocap bodies follow it. A buffer the next call with the same S, T overwrites."""
        samples, horizon, nu = control.shape
        if nu != self.model.nu:
            raise ValueError(f"control has {nu} channels per step; the model needs {self.model.nu}")
        wp = self._wp
        w = self._get_worlds(samples, horizon)
        self._start(w, x0)
        w.ctrl_seq_t.copy_(control.transpose(0, 1))
        with_path = mocap_path is not None and self.model.nmocap > 0
        if with_path:
            path = torch.as_tensor(np.asarray(mocap_path, dtype=np.float32)).to(self.device)
            w.mocap_seq_t.copy_(
                path.reshape(horizon, 1, self.model.nmocap, 3).expand(-1, samples, -1, -1)
            )
        with wp.ScopedDevice(self.wp_device):
            if self.wp_device.is_cuda:
                # torch filled the inputs on its stream, Warp runs on its own: order them
                torch.cuda.synchronize(self.device)
                graph = w.graphs.get(with_path)
                if graph is None and not self._compiled:
                    self._steps(w, horizon, with_path)  # first run: compiles the kernels
                    self._compiled = True
                    self._start(w, x0)
                    torch.cuda.synchronize(self.device)
                if graph is None:
                    with wp.ScopedCapture() as capture:
                        self._steps(w, horizon, with_path)
                    graph = w.graphs[with_path] = capture.graph
                wp.capture_launch(graph)
                wp.synchronize_device(self.wp_device)
            else:
                self._steps(w, horizon, with_path)
        w.sensordata.copy_(w.out_t.transpose(0, 1))
        self._flag_overflows(w)
        return w.sensordata

    def _flag_overflows(self, w: _Worlds) -> None:
        """NaN for the samples whose worlds ran out of contact or constraint buffers: their
        sensordata is truncated physics, so they must get no weight."""
        flags = self._wp.to_torch(w.data.overflow)
        bad = (flags & self._capacity) != 0
        if not bool(bad.any()):
            return
        w.sensordata[bad] = float("nan")
        seen = 0
        for v in flags[bad].tolist():
            seen |= int(v)
        for f in self._mjw.OverflowType:
            if (
                f.value
                and not f.value & (f.value - 1)
                and seen & f.value
                and f.name not in self._warned
            ):
                self._warned.add(f.name)
                log.warning(
                    "MJWarp buffer overflow (%s) in %d of %d rollouts: they get no weight; "
                    "raise planner.nconmax (contacts per world, now %d) or planner.njmax "
                    "(constraint rows, now %d)",
                    f.name,
                    int(bad.sum()),
                    len(bad),
                    self.nconmax,
                    self.njmax,
                )

    def close(self) -> None:
        self._worlds.clear()
