"""What the page draws: the scene from the scenario's model, the planner's best trajectories
coloured by mode, the executed path, and the side panel's text."""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from m3p2i.view_scene import GeomShape, camera_for, geom_poses, scene_bounds, scene_shapes
from shared.frames import FrameResolver
from shared.scenario import Scenario

MODE_COLOURS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
]


PATH_COLOUR = (20, 20, 20)


PANEL_HZ = 10.0  # text panel refreshes per second: readable, and cheap for the browser


SCENE_HZ = 30.0  # pose updates per second sent to the browser at most


PATH_STEP = 0.005  # m: executed-path points closer than this to the last one are skipped


def rgb255(rgba) -> tuple[int, int, int]:
    return tuple(round(255 * min(max(c, 0.0), 1.0)) for c in rgba[:3])


def trajectory_segments(
    top: np.ndarray, top_modes: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Line segments ``[S, 2, 3]`` and their colours ``[S, 2, 3]`` (uint8) of the sampled
    trajectories ``top [M, T, 3]``, each coloured by its mode (``top_modes [M]``; mode 0 when
    the planner did not say)."""
    top = np.asarray(top, float)
    if top.ndim != 3 or top.shape[1] < 2:
        return np.zeros((0, 2, 3)), np.zeros((0, 2, 3), np.uint8)
    modes = np.zeros(len(top), int) if top_modes is None else np.asarray(top_modes, int)
    segs = np.stack([top[:, :-1], top[:, 1:]], axis=2).reshape(-1, 2, 3)
    per_traj = np.array([MODE_COLOURS[m % len(MODE_COLOURS)] for m in modes], np.uint8)
    cols = np.repeat(per_traj, top.shape[1] - 1, axis=0)[:, None, :].repeat(2, axis=1)
    return segs, cols


def path_segments(points: np.ndarray) -> np.ndarray:
    """Consecutive points ``[P, 3]`` as segments ``[P-1, 2, 3]``."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) < 2:
        return np.zeros((0, 2, 3))
    return np.stack([points[:-1], points[1:]], axis=1)


def weight_bar(weight: float, width: int = 20) -> str:
    """A text bar for a mode weight in 0-1 (the panel's bar chart)."""
    w = min(max(float(weight), 0.0), 1.0)
    full = round(w * width)
    return "█" * full + "░" * (width - full)


@dataclass
class PanelInfo:
    """What the side panel shows, from the newest state and diagnostics."""

    scenario: str = ""
    status: str = "waiting for the world"
    time: float = 0.0
    action: str = ""
    alternatives: list[str] = field(default_factory=list)
    mode_names: list[str] = field(default_factory=list)
    mode_weights: list[float] = field(default_factory=list)
    planner_hz: float | None = None
    plan_ms: float | None = None
    samples: int | None = None  # per mode, under the anytime planner's budget
    horizon: int | None = None  # the plan's steps, under that budget
    extras: dict[str, float] = field(default_factory=dict)
    model: dict[str, float] = field(default_factory=dict)  # identified: "mass.box" -> factor
    note: str = ""

    def markdown(self) -> str:
        lines = [f"**{self.scenario}** — {self.status}, t = {self.time:.2f} s", ""]
        lines.append(f"**action**: `{self.action or '—'}`")
        if self.alternatives:
            lines.append("**alternatives**: " + ", ".join(f"`{a}`" for a in self.alternatives))
        if self.mode_names:
            lines += ["", "**mode weights**", ""]
            for i, (name, w) in enumerate(zip(self.mode_names, self.mode_weights)):
                r, g, b = MODE_COLOURS[i % len(MODE_COLOURS)]
                lines.append(
                    f"<span style='color:rgb({r},{g},{b})'>{weight_bar(w)}</span> "
                    f"{w:.2f} `{name}`  "
                )
        if self.planner_hz is not None:
            lines += [
                "",
                f"**planner**: {self.planner_hz:.1f} Hz"
                + (f", {self.plan_ms:.0f} ms per plan" if self.plan_ms is not None else "")
                + (f", {self.samples} samples per mode" if self.samples is not None else "")
                + (f", {self.horizon} steps" if self.horizon is not None else ""),
            ]
        for k, v in self.extras.items():
            lines.append(f"**{k}**: {v:.1f}")
        if self.model:  # planner.model.variants: the planner's estimate of the world's model
            lines += ["", "**identified model** (× nominal)", ""]
            lines += [f"`{k}` {v:.2f}  " for k, v in sorted(self.model.items())]
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines)


class SceneDrawing:
    """The scenario's model drawn in a viser scene: meshes once, then poses, the planner's
    sampled trajectories and the executed path."""

    def __init__(self, server, model: mujoco.MjModel, data: mujoco.MjData):
        self.server = server
        self.model = model
        self.shapes: list[GeomShape] = scene_shapes(model)
        server.scene.set_up_direction("+z")
        self.handles = {}
        pos, quat = geom_poses(model, data)
        for s in self.shapes:
            self.handles[s.geom_id] = server.scene.add_mesh_simple(
                f"/world/{s.name}",
                s.vertices,
                s.faces,
                color=rgb255(s.rgba),
                opacity=None if s.rgba[3] >= 1 else float(s.rgba[3]),
                side="double" if s.kind == "plane" else "front",
                flat_shading=s.kind == "box",
                wxyz=quat[s.geom_id],
                position=pos[s.geom_id],
            )
        self.moving = [s.geom_id for s in self.shapes if s.movable]
        self._top = None
        self._path = None
        self._guide = None
        lo, hi = scene_bounds(model, data, self.shapes)
        # every new page (and the client's "reset view") starts framing the scene
        position, look_at = camera_for(lo, hi)
        server.initial_camera.position = tuple(position)
        server.initial_camera.look_at = tuple(look_at)
        self.scale = float(np.linalg.norm(hi - lo))
        self._line = max(0.002, 0.0025 * self.scale)

    def set_poses(self, data: mujoco.MjData) -> None:
        pos, quat = geom_poses(self.model, data)
        with self.server.atomic():
            for g in self.moving:
                h = self.handles[g]
                h.position = pos[g]
                h.wxyz = quat[g]

    def set_top(self, top: np.ndarray | None, top_modes: np.ndarray | None) -> None:
        segs, cols = trajectory_segments(top if top is not None else np.zeros((0, 0, 3)), top_modes)
        if self._top is not None:
            self._top.remove()
            self._top = None
        if len(segs):
            self._top = self.server.scene.add_line_segments(
                "/planner/top", segs.astype(np.float32), cols, thickness=self._line
            )

    def set_guide(self, corners: np.ndarray | None) -> None:
        """The scenario guide's path (its corners ``[N, 3]``), or none."""
        segs = path_segments(corners if corners is not None else np.zeros((0, 3)))
        if self._guide is not None:
            self._guide.remove()
            self._guide = None
        if len(segs):
            cols = np.tile(np.array([242, 191, 26], np.uint8), (len(segs), 2, 1))
            self._guide = self.server.scene.add_line_segments(
                "/planner/guide", segs.astype(np.float32), cols, thickness=2 * self._line
            )

    def set_path(self, points: np.ndarray) -> None:
        segs = path_segments(points)
        if self._path is not None:
            self._path.remove()
            self._path = None
        if len(segs):
            self._path = self.server.scene.add_line_segments(
                "/world/executed_path",
                segs.astype(np.float32),
                PATH_COLOUR,
                thickness=self._line * 1.5,
            )


def robot_frame(scenario: Scenario, model: mujoco.MjModel):
    """The frame the planner's trajectories are positions of (the robot's ``frame``)."""
    return FrameResolver(model, scenario.robot.spec.frame)("robot")
