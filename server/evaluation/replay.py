"""Replaying logged states into a MuJoCo model: the kinematics behind metrics, plots and videos.

A ``step`` record of the episode log holds ``qpos``, ``qvel``, ``act``, ``mocap_pos`` and
``mocap_quat`` after that world step; copying them into an ``MjData`` of the scenario's compiled
model and calling ``mj_forward`` gives back every frame pose and contact the world had at that
moment, without re-simulating anything.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import mujoco
import numpy as np

from shared.frames import Frame, FrameResolver
from shared.scenario import Scenario
from shared.scene import STATE_FIELDS, set_state


def load_step(model: mujoco.MjModel, data: mujoco.MjData, step: dict) -> None:
    """Copy one logged state into ``data`` and recompute kinematics and contacts.

    Logs written before ``act`` was logged restore actuator activations as zeros (no shipped
    robot has any)."""
    values = {name: step.get(name, []) for name in STATE_FIELDS}
    if "act" not in step:
        values["act"] = np.zeros(model.na)
    try:
        set_state(model, data, values)
    except ValueError as exc:
        raise ValueError(
            f"step {step.get('seq')}: {exc} (was the log written for another scenario?)"
        ) from None
    mujoco.mj_forward(model, data)


def replay(model: mujoco.MjModel, steps: Iterable[dict]) -> Iterator[mujoco.MjData]:
    """One ``MjData`` (reused: read it before advancing) per logged step, kinematics computed."""
    data = mujoco.MjData(model)
    for step in steps:
        load_step(model, data, step)
        yield data


def resolve_frame(scenario: Scenario, model: mujoco.MjModel, name: str, key: str) -> Frame:
    """A YAML frame name of the scenario, or a ConfigError naming ``key`` and the valid names."""
    return FrameResolver(model, scenario.robot.spec.frame).checked(name, scenario.source, key)


def frame_tracks(
    model: mujoco.MjModel, steps: list[dict], frames: dict[str, Frame]
) -> dict[str, np.ndarray]:
    """World positions ``[len(steps), 3]`` of each named frame over the logged steps."""
    out = {name: np.empty((len(steps), 3)) for name in frames}
    for i, data in enumerate(replay(model, steps)):
        for name, frame in frames.items():
            out[name][i] = frame.pos(data)
    return out
