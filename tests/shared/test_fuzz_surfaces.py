"""The newer surfaces a user's files reach, fuzzed (Hypothesis) at their edges: robot files and
their MJCF's actuators (ranges, limits, safe control, units), ``planner.model.variants``,
``guide:`` and ``sensors:``. Every case loads or raises ``ConfigError`` naming the file and a
key; a robot that loads holds still on its safe control with finite controls and state, and the
variants, guide grid and sensors a loaded scenario asks for stay within their stated bounds.

Derandomized, no example database, sized to a few seconds."""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.config import ConfigError, ConfigErrors, load_yaml
from shared.robots import UNITS
from shared.scenario import find_scenario, load_scenario
from shared.scenario.guide import GUIDE_MAX_CELLS, grid_cells
from shared.scenario.variants import MAX_VARIANT_ROLLOUTS, MAX_VARIANTS
from tests.user_folder import TWO_LINK, TWO_LINK_XML, user_folder

FUZZ = settings(
    max_examples=80,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=list(HealthCheck),
)
EDGES = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -0.0, 0.0, 1.5, -1.5, 1e-9]
# edges, and plain values between them, so that about half the cases load and go on
edge = st.one_of(st.sampled_from(EDGES), st.floats(-3, 3), st.floats(-3, 3))
word = st.sampled_from(["", "x", "true", "false", "auto", "1 2 3", "nan", "-inf inf"])


def _load_or_named_error(path) -> object | None:
    """The scenario, or None after a ConfigError that names a file and a key."""
    try:
        return load_scenario(path)
    except ConfigError as exc:
        for e in exc.errors if isinstance(exc, ConfigErrors) else [exc]:
            assert e.source and e.path, f"no file or key named: {e}"
        return None


def _fmt(v: float) -> str:
    return "nan" if math.isnan(v) else repr(v)


KINDS = {'velocity kv="2"': "rad/s", 'position kp="5"': "rad", "motor": "N·m"}


@st.composite
def robot_files(draw) -> tuple[str, dict]:
    """The two-link arm with one of its elbow actuator's range, limit flag, kind, unit or safe
    control drawn at its edges (or none: a good file), the others good."""
    which = draw(st.sampled_from(["none", "range", "limited", "kind", "unit", "safe"]))
    lo, hi = -1.5, 1.5
    if which == "range":
        lo, hi = draw(edge), draw(edge)
        if draw(st.booleans()):
            lo, hi = sorted((lo, hi))
    attrs = f'ctrlrange="{_fmt(lo)} {_fmt(hi)}"'
    if which == "limited":
        attrs += f' ctrllimited="{draw(st.sampled_from(["true", "false", "auto", "x"]))}"'
    kind = draw(st.sampled_from(sorted(KINDS))) if which in ("kind", "unit") else 'velocity kv="2"'
    unit = KINDS[kind]
    if which == "unit":
        unit = draw(st.one_of(st.sampled_from(UNITS), word))
    elbow = '<velocity name="elbow_vel" joint="elbow"/>'
    assert elbow in TWO_LINK_XML
    xml = TWO_LINK_XML.replace(elbow, f'<{kind} name="elbow_vel" joint="elbow" {attrs}/>')
    robot = copy.deepcopy(TWO_LINK)
    robot["controls"] = {"shoulder_vel": "rad/s", "elbow_vel": unit}
    if which == "safe":
        robot["safe_ctrl"] = [0.0, draw(st.one_of(edge, word))]
    return xml, robot


@FUZZ
@given(case=robot_files())
def test_a_robot_file_at_its_edges_loads_and_holds_still_or_names_its_key(tmp_path_factory, case):
    xml, robot = case
    root = tmp_path_factory.mktemp("robot")
    path = user_folder(root, robot)
    (path.parent.parent / "robots" / "two_link.xml").write_text(xml)
    sc = _load_or_named_error(path)
    if sc is None:
        return
    model = mujoco.MjModel.from_xml_path(str(sc.robot.spec.path))
    lo, hi = model.actuator_ctrlrange.T
    assert model.actuator_ctrllimited.all() and np.isfinite([lo, hi]).all() and (lo < hi).all()
    data = mujoco.MjData(model)
    data.ctrl[:] = sc.robot.spec.safe_stop()
    assert ((lo <= data.ctrl) & (data.ctrl <= hi)).all()
    for _ in range(20):
        mujoco.mj_step(model, data)
    assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()


def _leaves(node: dict, prefix: tuple = ()) -> list[tuple]:
    out = []
    for key, value in node.items():
        path = (*prefix, key)
        out.extend(_leaves(value, path) if isinstance(value, dict) else [path])
    return out


def _mutated(name: str, section: tuple[str, ...], extra: list[str], data) -> dict:
    """Scenario ``name`` with one or two values under ``section`` (its own, or keys of
    ``extra`` it leaves at their defaults) replaced by edges or plain values."""
    return _mutated_node(copy.deepcopy(load_yaml(find_scenario(name))), section, extra, data)


def _mutated_node(raw: dict, section: tuple, extra: list[str], data) -> dict:
    node = raw
    for key in section:
        node = node[key]
    for _ in range(data.draw(st.integers(1, 2))):
        path = data.draw(st.sampled_from(_leaves(node) + [(k,) for k in extra]))
        parent = node
        for key in path[:-1]:
            parent = parent[key]
        parent[path[-1]] = data.draw(
            st.one_of(
                edge,
                word,
                st.sampled_from([0, -1, 1, 2, 10**6, 2**63, 10**400]),
                st.integers(1, 400),
                st.floats(1e-4, 2.0),
                st.none(),
                st.lists(edge, max_size=3),
            )
        )
    return raw


@FUZZ
@given(data=st.data())
def test_variants_at_their_edges_load_within_their_bounds_or_name_the_key(tmp_path_factory, data):
    extra = ["seed", "aggregate", "cvar_alpha"]
    raw = _mutated("pull_lab_variants", ("planner", "model", "variants"), extra, data)
    path = tmp_path_factory.mktemp("variants") / "v.yaml"
    path.write_text(yaml.safe_dump(raw))
    sc = _load_or_named_error(path)
    if sc is None:
        return
    v = sc.planner.model.variants
    assert 1 <= v.count <= MAX_VARIANTS
    if v.spread == "all":
        assert v.count * sc.planner.samples <= MAX_VARIANT_ROLLOUTS


@FUZZ
@given(data=st.data())
def test_a_guide_at_its_edges_loads_within_its_grid_bound_or_names_the_key(tmp_path_factory, data):
    extra = ["radius", "room", "gap", "replan_distance", "replan_move", "obstacles"]
    raw = _mutated("navigation_trap_guided", ("guide",), extra, data)
    path = tmp_path_factory.mktemp("guide") / "g.yaml"
    path.write_text(yaml.safe_dump(raw))
    sc = _load_or_named_error(path)
    if sc is None:
        return
    assert grid_cells(sc.guide.resolution, sc.world.span()) <= GUIDE_MAX_CELLS


SENSORS = [
    {"name": "lidar", "type": "lidar", "pos": [0.0, 0.0, 0.25], "range": [0.05, 6.0]},
    {"name": "camera", "type": "depth", "pos": [0.0, 0.0, 2.0], "look_at": [0.0, 0.0, 0.0]},
]


@FUZZ
@given(data=st.data())
def test_sensor_keys_at_their_edges_load_within_their_bounds_or_name_the_key(
    tmp_path_factory, data
):
    raw = copy.deepcopy(load_yaml(find_scenario("navigation")))
    raw["sensors"] = copy.deepcopy(SENSORS)
    extra = ["rays", "fov", "rate", "frame", "width", "height", "fovy", "euler"]
    raw = _mutated_node(raw, ("sensors", data.draw(st.sampled_from([0, 1]))), extra, data)
    path = tmp_path_factory.mktemp("sensors") / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    sc = _load_or_named_error(path)
    if sc is None:
        return
    for s in sc.sensors:
        assert 0 <= s.range[0] < s.range[1] and 0 < s.rate <= 100
        if s.kind == "lidar":
            assert 1 <= s.rays <= 4096 and 0 < s.fov <= 360
        else:
            assert s.width * s.height <= 320 * 240 and 0 < s.fovy < 180
