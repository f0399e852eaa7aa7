"""A user's folder outside the package, laid out like the shipped ``configs/``: a two-link planar
arm of the user's own (``robots/two_link.xml`` and its robot file) and a reaching scenario for it
(``scenarios/reach.yaml``). Shared by tests/cli/test_user_robots.py and
tests/planner_client/test_plugins.py."""

from __future__ import annotations

from pathlib import Path

import yaml

TWO_LINK_XML = """<mujoco model="two_link">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.05" integrator="implicitfast"/>
  <default>
    <velocity kv="2" ctrlrange="-1.5 1.5"/>
    <geom contype="0" conaffinity="0"/>
  </default>
  <worldbody>
    <body name="base" pos="0 0 0.5">
      <geom type="cylinder" size="0.05 0.05"/>
      <body name="upper">
        <joint name="shoulder" type="hinge" axis="0 0 1" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.5"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 0 1" range="-2.8 2.8" damping="0.1"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.3"/>
          <site name="tip" pos="0.3 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <velocity name="shoulder_vel" joint="shoulder"/>
    <velocity name="elbow_vel" joint="elbow"/>
  </actuator>
</mujoco>
"""

TWO_LINK = {
    "description": "a two-link planar arm of the lab's",
    "mjcf": "two_link.xml",
    "frame": "site:tip",
    "controls": {"shoulder_vel": "rad/s", "elbow_vel": "rad/s"},
}

DISTANCE_TERMS = [
    {"term": "distance", "a": "robot", "b": "target", "weight": 1.0},
    {"term": "distance", "a": "robot", "b": "target", "weight": 4.0, "when": "terminal"},
]


def reach(robot: dict | None = None, terms: list | None = None, **extra) -> dict:
    """The reaching scenario: the arm's tip to a target that needs both joints to move (the tip
    starts 0.55 m from it), few samples and a short horizon to stay fast."""
    return {
        "name": "reach",
        "description": "The lab's two-link arm reaches a target.",
        "robot": robot or {"model": "two_link", "qpos": [0.0, 0.5]},
        "world": {
            "timestep": 0.05,
            "objects": [
                {
                    "name": "target",
                    "shape": "sphere",
                    "size": [0.03],
                    "pos": [0.1, 0.45, 0.5],
                    "visual": True,
                }
            ],
        },
        "episode": {
            "max_time": 10.0,
            "success": [{"near": {"a": "robot", "b": "target", "within": 0.03}}],
        },
        "planner": {"samples": 40, "horizon": 8},
        "objectives": {"reach": {"terms": terms or DISTANCE_TERMS}},
        "modes": ["reach"],
        **extra,
    }


def user_folder(root: Path, robot: dict | None = None, scenario: dict | None = None) -> Path:
    """``root/configs`` with the arm and the scenario; returns the scenario's path."""
    robots, scenarios = root / "configs" / "robots", root / "configs" / "scenarios"
    robots.mkdir(parents=True, exist_ok=True)
    scenarios.mkdir(parents=True, exist_ok=True)
    (robots / "two_link.xml").write_text(TWO_LINK_XML)
    (robots / "two_link.yaml").write_text(yaml.safe_dump(robot or TWO_LINK, sort_keys=False))
    path = scenarios / "reach.yaml"
    path.write_text(yaml.safe_dump(scenario or reach(), sort_keys=False))
    return path
