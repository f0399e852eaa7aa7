"""Rotation utilities and the orientation metric for fully symmetric objects (paper Eq. 33)."""

from __future__ import annotations

import itertools
import math

import mujoco
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from planner_client.costs.poses import symmetric_orientation_error_relative
from shared.geometry import symmetric_orientation_error


def rot(axis, degrees) -> np.ndarray:
    return Rotation.from_rotvec(
        np.radians(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)
    ).as_matrix()


def random_rotations(n: int, seed: int) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_matrix()


def cube_symmetries() -> list[np.ndarray]:
    """The 24 proper rotations mapping a cube onto itself: signed permutations with det +1."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((-1, 1), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


# ---------------------------------------------------------------- phi (paper Eq. 33) --------------


def test_identical_frames_give_zero():
    frames = random_rotations(20, seed=1)
    np.testing.assert_allclose(
        symmetric_orientation_error(frames, frames), np.zeros(20), atol=1e-12, rtol=0
    )


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1)])
@pytest.mark.parametrize("degrees", [90, 180, 270, -90])
def test_quarter_turns_about_any_axis_give_zero(axis, degrees):
    base = random_rotations(1, seed=2)[0]
    turned = base @ rot(axis, degrees)  # turned about the object's own axis
    assert float(symmetric_orientation_error(base, turned)) == pytest.approx(0.0, abs=1e-12)
    assert float(symmetric_orientation_error(turned, base)) == pytest.approx(0.0, abs=1e-12)


def test_all_24_cube_symmetries_including_flips_give_zero():
    base = random_rotations(1, seed=3)[0]
    flipped = np.stack([base @ s for s in cube_symmetries()])
    assert len(flipped) == 24
    # e.g. a cube flipped upside down about a face diagonal: x -> y, y -> x, z -> -z
    assert any(np.allclose(s, rot((1, 1, 0), 180)) for s in cube_symmetries())
    phi = symmetric_orientation_error(base, flipped)
    np.testing.assert_allclose(phi, np.zeros(24), atol=1e-12, rtol=0)


def test_45_degree_yaw_by_hand():
    # u = identity: u1 = (1, 0, 0), u2 = (0, 1, 0). v = yaw by 45 deg, c = s = 1/sqrt(2):
    #   v1 = (c, s, 0), v2 = (-s, c, 0), v3 = (0, 0, 1)
    #   |u1 . v_i| = (c, s, 0)  -> max 1/sqrt(2)
    #   |u2 . v_j| = (s, c, 0)  -> max 1/sqrt(2)
    #   phi = min_{i,j} 2 - |u1 . v_i| - |u2 . v_j| = 2 - 2/sqrt(2) = 2 - sqrt(2) = 0.5858
    # 45 deg is the farthest a yaw can get from a cube's symmetry, so this is the largest
    # error a cube lying on a table can show.
    phi = symmetric_orientation_error(np.eye(3), rot((0, 0, 1), 45))
    assert float(phi) == pytest.approx(2 - math.sqrt(2), abs=1e-12)


@pytest.mark.parametrize("degrees", np.linspace(-180, 180, 37))
def test_yaw_error_is_periodic_in_quarter_turns(degrees):
    # phi = 2 - 2 max(|cos a|, |sin a|): 0 at multiples of 90 deg, largest at 45 deg
    a = math.radians(degrees)
    expected = 2 - 2 * max(abs(math.cos(a)), abs(math.sin(a)))
    phi = symmetric_orientation_error(np.eye(3), rot((0, 0, 1), degrees))
    assert float(phi) == pytest.approx(expected, abs=1e-12)


def test_zero_only_for_general_equivalence():
    # any rotation that is not a cube symmetry leaves some axis misaligned
    frames = random_rotations(500, seed=4)
    assert float(symmetric_orientation_error(np.eye(3), frames).min()) > 1e-4


def test_invariances():
    u, v = random_rotations(200, seed=5), random_rotations(200, seed=6)
    phi = symmetric_orientation_error(u, v)
    world = random_rotations(1, seed=7)[0]
    # the same rotation of both frames (a change of world frame) changes nothing
    torch.testing.assert_close(symmetric_orientation_error(world @ u, world @ v), phi)
    # relabelling or flipping the axes of v (a cube symmetry of the target) changes nothing
    for sym in cube_symmetries():
        torch.testing.assert_close(symmetric_orientation_error(u, v @ sym), phi)
    # the metric stays in its bounds
    assert float(phi.min()) >= 0.0 and float(phi.max()) <= 2 - 2 / math.sqrt(3)


def test_symmetric_in_its_arguments_for_rotations_about_the_first_frames_third_axis():
    # phi(u, v) reads rows 1-2 of u^T v, phi(v, u) columns 1-2; they agree when the relative
    # rotation is about u's third axis -- e.g. a cube lying on a table and its goal, both yawed
    u = random_rotations(50, seed=8)
    yaws = np.stack([rot((0, 0, 1), d) for d in np.linspace(-170, 170, 50)])
    v = u @ yaws
    torch.testing.assert_close(symmetric_orientation_error(u, v), symmetric_orientation_error(v, u))


def test_not_symmetric_for_general_pairs_as_eq_33_is_written():
    # paper Eq. 33 matches only u's first two axes, so swapping the frames can change phi (by up to
    # ~0.3 for random pairs). Guard against a silent "fix": this is the thesis' metric.
    u, v = random_rotations(200, seed=9), random_rotations(200, seed=10)
    difference = np.abs(symmetric_orientation_error(u, v) - symmetric_orientation_error(v, u))
    assert float(difference.max()) > 0.05
    # but it is symmetric where it matters most: at zero (general equivalence is symmetric)
    w = u[0] @ cube_symmetries()[5]
    assert float(symmetric_orientation_error(w, u[0])) == pytest.approx(0.0, abs=1e-12)


def test_batched_shapes_broadcast_against_one_goal():
    samples = torch.as_tensor(random_rotations(6 * 4, seed=11)).reshape(6, 4, 3, 3)
    goal = rot((1, 2, 3), 40)
    phi = symmetric_orientation_error(samples, goal)
    assert phi.shape == (6, 4)
    for s, t in itertools.product(range(6), range(4)):
        assert float(phi[s, t]) == pytest.approx(
            float(symmetric_orientation_error(samples[s, t], goal)), abs=1e-12
        )


def test_mixed_inputs_follow_the_tensor_argument():
    u = torch.as_tensor(random_rotations(3, seed=12), dtype=torch.float32)
    phi = symmetric_orientation_error(u, np.eye(3))
    assert phi.dtype == torch.float32 and phi.device == u.device and phi.shape == (3,)


def test_numpy_inputs_stay_in_numpy_and_agree_with_torch():
    # the world server's success tests call it with NumPy and must not need torch
    u, v = random_rotations(40, seed=14), random_rotations(40, seed=15)
    phi = symmetric_orientation_error(u, v)
    assert isinstance(phi, np.ndarray) and phi.dtype == np.float64 and phi.shape == (40,)
    torch.testing.assert_close(
        torch.as_tensor(phi), symmetric_orientation_error(torch.as_tensor(u), v), atol=1e-12, rtol=0
    )


def _axes_in(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``[..., 9]``: the x, y, z axes of frames ``v [..., 3, 3]`` in the coordinates of frames
    ``u``, one after the other (MuJoCo's frame axis sensors of v with u as reference)."""
    return np.swapaxes(np.swapaxes(u, -1, -2) @ v, -1, -2).reshape(*u.shape[:-2], 9)


def test_relative_axes_version_matches_rotation_matrices():
    u = Rotation.random(30, random_state=13).as_matrix()
    goal = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    expected = torch.as_tensor(symmetric_orientation_error(u, goal))
    got = symmetric_orientation_error_relative(torch.as_tensor(_axes_in(u, goal)))
    torch.testing.assert_close(got, expected, atol=1e-12, rtol=0)
    # the argument order is the matrices' (u's first two axes are matched); batches [S, T]
    samples = Rotation.random(12, random_state=4).as_matrix().reshape(4, 3, 3, 3)
    got = symmetric_orientation_error_relative(torch.as_tensor(_axes_in(samples, goal)))
    assert got.shape == (4, 3)
    torch.testing.assert_close(
        got, torch.as_tensor(symmetric_orientation_error(samples, goal)), atol=1e-12, rtol=0
    )


def test_relative_axes_version_reads_mujoco_frame_sensors_and_a_cube_symmetry_costs_nothing():
    xml = """<mujoco><worldbody>
      <body name="u" quat="0.9 0.2 -0.3 0.4"><freejoint/><geom size="0.1"/></body>
      <body name="v" pos="1 0 0" quat="0.1 0.7 0.5 -0.2"><freejoint/><geom size="0.1"/></body>
    </worldbody><sensor>
      <framexaxis objtype="body" objname="v" reftype="body" refname="u"/>
      <frameyaxis objtype="body" objname="v" reftype="body" refname="u"/>
      <framezaxis objtype="body" objname="v" reftype="body" refname="u"/>
    </sensor></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    u, v = d.body("u").xmat.reshape(3, 3), d.body("v").xmat.reshape(3, 3)
    got = symmetric_orientation_error_relative(torch.as_tensor(d.sensordata.copy()))
    assert float(got) == pytest.approx(float(symmetric_orientation_error(u, v)), abs=1e-12)
    assert float(got) > 0.1
    # v turned onto u up to a quarter turn about u's x axis and a flip: a cube symmetry
    d.qpos[10:14] = d.qpos[3:7]
    turn = Rotation.from_euler("xz", [90, 180], degrees=True).as_quat(scalar_first=True)
    mujoco.mju_mulQuat(d.qpos[10:14], d.qpos[3:7].copy(), turn)
    mujoco.mj_forward(m, d)
    got = symmetric_orientation_error_relative(torch.as_tensor(d.sensordata.copy()))
    assert float(got) == pytest.approx(0.0, abs=1e-12)
