"""Named frames of a compiled scenario model: where "robot", "box" or "goal" is.

Scenario YAML names frames by body name (objects, markers), ``robot`` for the robot's frame from
its :class:`~shared.robots.RobotSpec`, or ``site:NAME`` for a site. Both processes resolve names
the same way, so a success test on the server and an observer in the planner agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from shared.config import ConfigError


@dataclass(frozen=True)
class Frame:
    name: str
    kind: int  # mujoco.mjtObj.mjOBJ_BODY or mjOBJ_SITE
    id: int

    def pos(self, data: mujoco.MjData) -> np.ndarray:
        """World position [3]."""
        return (
            data.xpos[self.id] if self.kind == mujoco.mjtObj.mjOBJ_BODY else data.site_xpos[self.id]
        )

    def rot(self, data: mujoco.MjData) -> np.ndarray:
        """World rotation matrix [3, 3] (columns are the frame's axes)."""
        flat = (
            data.xmat[self.id] if self.kind == mujoco.mjtObj.mjOBJ_BODY else data.site_xmat[self.id]
        )
        return flat.reshape(3, 3)


class FrameResolver:
    """Resolves YAML frame names against one compiled model."""

    def __init__(self, model: mujoco.MjModel, robot_frame: str):
        self.model = model
        self.robot_frame = robot_frame

    def mujoco_ref(self, name: str) -> tuple[int, str]:
        """(mjtObj, mujoco name) for a YAML frame name, e.g. for sensors' objtype/objname."""
        if name == "robot":
            name = self.robot_frame
        if name.startswith("site:"):
            return mujoco.mjtObj.mjOBJ_SITE, name[5:]
        return mujoco.mjtObj.mjOBJ_BODY, name

    def __call__(self, name: str) -> Frame:
        kind, mj_name = self.mujoco_ref(name)
        fid = mujoco.mj_name2id(self.model, kind, mj_name)
        if fid < 0:
            what = "site" if kind == mujoco.mjtObj.mjOBJ_SITE else "body"
            raise KeyError(f"no {what} named {mj_name!r} in the model (frame {name!r})")
        return Frame(name, kind, fid)

    def checked(self, name: str, source: str, key: str) -> Frame:
        """The frame of a YAML name, or a ConfigError naming the file, the key path, the name
        and every valid name: the one place such an error is worded."""
        try:
            return self(name)
        except KeyError as exc:
            raise ConfigError(
                source, key, str(exc.args[0]), name, f"one of: {', '.join(self.names())}"
            ) from None

    def names(self) -> list[str]:
        """Every name a YAML file may use, once each, for error messages (a robot whose frame
        body is itself called ``robot`` is listed once)."""
        bodies = [
            mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY, i)
            for i in range(1, self.model.nbody)
        ]
        sites = [
            f"site:{mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_SITE, i)}"
            for i in range(self.model.nsite)
        ]
        return list(
            dict.fromkeys(["robot"] + [n for n in bodies + sites if n and n != "site:None"])
        )
