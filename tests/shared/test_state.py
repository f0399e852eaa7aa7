"""One way to copy a world state into MjData (the planner's mirror, log replay), with every
field, ``act`` included; and one axis selection for every distance."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from server.evaluation.metrics import position_error
from server.evaluation.replay import load_step
from shared.geometry import AXES, select_axes
from shared.scene import STATE_FIELDS, set_state

# a slide joint driven by a filtered actuator: one activation (na = 1), one mocap body
XML = """
<mujoco>
  <worldbody>
    <body name="cart"><joint name="x" type="slide"/><geom size="0.1"/></body>
    <body name="marker" mocap="true"><geom size="0.05" contype="0" conaffinity="0"/></body>
  </worldbody>
  <actuator><general joint="x" dyntype="filter" dynprm="0.1"/></actuator>
</mujoco>
"""


@pytest.fixture
def model():
    return mujoco.MjModel.from_xml_string(XML)


def _state(**over):
    values = {
        "qpos": [0.3],
        "qvel": [0.1],
        "act": [0.7],
        "mocap_pos": [1.0, 2.0, 3.0],
        "mocap_quat": [1.0, 0.0, 0.0, 0.0],
    }
    return {**values, **over}


def test_set_state_copies_every_field(model):
    data = mujoco.MjData(model)
    set_state(model, data, _state())
    for name in STATE_FIELDS:
        np.testing.assert_allclose(getattr(data, name).ravel(), np.ravel(_state()[name]))


def test_set_state_names_a_field_of_the_wrong_size(model):
    with pytest.raises(ValueError, match="act has 2 values, the model needs 1"):
        set_state(model, mujoco.MjData(model), _state(act=[0.1, 0.2]))


def test_a_replayed_step_restores_the_activation(model):
    data = mujoco.MjData(model)
    load_step(model, data, {"seq": 4, **_state()})
    assert data.act[0] == pytest.approx(0.7)


def test_a_log_from_before_act_was_logged_replays_with_zero_activation(model):
    data = mujoco.MjData(model)
    data.act[:] = 5.0
    step = {"seq": 4, **_state()}
    del step["act"]
    load_step(model, data, step)
    assert data.act[0] == 0.0


def test_the_server_logs_every_state_field_with_each_step(tmp_path):
    from m3p2i.launch import free_port_block
    from server.app import WorldServer
    from server.evaluation.log_reader import read_log, steps
    from shared.endpoints import Endpoints
    from shared.scenario import load_scenario

    server = WorldServer(
        load_scenario("push_pull"), Endpoints(port=free_port_block()), tmp_path / "episode.jsonl"
    )
    try:
        server.step(None)  # one safe-stop step, as without a planner
    finally:  # a server left open blocks its ZeroMQ context's clean-up, and the next test hangs
        server.log.close()
        server.close()
    (step,) = steps(read_log(tmp_path / "episode.jsonl"))
    assert set(STATE_FIELDS) <= set(step)


@pytest.mark.parametrize("axes", sorted(AXES))
def test_metrics_position_error_measures_along_each_axes_value(axes):
    a, b = np.array([1.0, 2.0, 3.0]), np.zeros(3)
    expected = float(np.linalg.norm(a[list(AXES[axes])]))
    assert position_error(a, b, axes) == pytest.approx(expected)


def test_select_axes_keeps_numpy_and_torch_and_rejects_unknown_axes():
    x = np.arange(6.0).reshape(2, 3)
    assert isinstance(select_axes(x, "xz"), np.ndarray)
    assert select_axes(torch.as_tensor(x), "yz").tolist() == [[1.0, 2.0], [4.0, 5.0]]
    with pytest.raises(ValueError, match="unknown axes 'zz'"):
        select_axes(x, "zz")
