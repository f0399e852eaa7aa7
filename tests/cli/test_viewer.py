"""Dragging objects by hand in the world server's viewer (`m3p2i-server --window`).

MuJoCo's passive viewer applies the mouse's perturbation when its owner calls ``sync()``: a
force/torque in ``data.xfrc_applied`` for a body, a new pose in ``data.mocap_pos`` for a mocap
body. There is no display here, so a stand-in viewer does exactly that; what is tested is the
server's side of the contract: it syncs the viewer after every step, keeps what the viewer
wrote for the next step, and publishes the moved objects to the planner.
"""

from __future__ import annotations

import mujoco
import numpy as np

from m3p2i.cli import free_port_block
from server.app import WorldServer
from shared.endpoints import Endpoints
from shared.scenario import load_scenario


class DraggingViewer:
    """Drags ``body`` with ``force`` (N, world frame) or, for a mocap body, moves it by
    ``shift`` (m) per sync, as the passive viewer does while the mouse is held."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        body: str,
        force=(0.0, 0.0, 0.0),
        shift=(0.0, 0.0, 0.0),
    ):
        self.data = data
        self.body = model.body(body).id
        self.mocap = int(model.body_mocapid[self.body])
        self.force, self.shift = np.array(force), np.array(shift)
        self.syncs = 0

    def sync(self) -> None:
        self.syncs += 1
        if self.mocap >= 0:
            self.data.mocap_pos[self.mocap] += self.shift
        else:
            self.data.xfrc_applied[self.body, :3] = self.force


def _server(scenario: str, tmp_path) -> WorldServer:
    return WorldServer(
        load_scenario(scenario), Endpoints(port=free_port_block()), tmp_path / "episode.jsonl"
    )


def test_a_cube_dragged_in_the_viewer_moves_in_the_published_state(tmp_path):
    server = _server("pick_place", tmp_path)
    try:
        cube = server.world.model.body("cube_a")
        adr = server.world.model.jnt_qposadr[cube.jntadr[0]]
        before = server.world.state().qpos[adr : adr + 3].copy()
        # 0.05 kg cube: 1 N lifts it against gravity (0.49 N) and pulls it towards the robot
        server.viewer = DraggingViewer(
            server.world.model, server.world.data, "cube_a", force=(-0.3, 0.0, 1.0)
        )
        for _ in range(30):
            server.step(None)  # one world step with the robot held still
        after = server.world.state().qpos[adr : adr + 3]
    finally:
        server.close()
    assert server.viewer.syncs == 30
    assert after[2] - before[2] > 0.02  # lifted off the table
    assert after[0] - before[0] < -0.005  # and dragged towards the robot


def test_a_fixed_object_dragged_in_the_viewer_is_published_where_it_was_put(tmp_path):
    server = _server("pick_place_reactive", tmp_path)
    try:
        mocap = server.world.model.body_mocapid[server.world.model.body("blocker").id]
        start = server.world.data.mocap_pos[mocap].copy()
        server.viewer = DraggingViewer(
            server.world.model, server.world.data, "blocker", shift=(0.0, -0.01, 0.0)
        )
        for _ in range(10):
            server.step(None)
        published = server.world.state().mocap_pos[mocap]
    finally:
        server.close()
    np.testing.assert_allclose(published, start + [0.0, -0.1, 0.0], atol=1e-9)
