"""Robot models: every registry entry matches its MJCF, and each robot does what its file says.

The scenes here are built the way :mod:`shared.scene` builds them (robot file as the base spec,
floor plane and objects added to the world body), but by hand, so these tests only depend on the
robot files.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shared.robots import ROBOTS, get_robot

BUILT_IN = ("point_robot", "point_robot_suction", "diff_drive", "panda")


def load(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(get_robot(name).path))


def with_world(name: str, add) -> mujoco.MjModel:
    """Compile robot ``name`` plus a floor and whatever ``add(worldbody)`` puts in the world."""
    spec = mujoco.MjSpec.from_file(str(get_robot(name).path))
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1])
    add(spec.worldbody)
    return spec.compile()


def add_box(
    world, name: str, half: list[float], pos: list[float], mass: float, friction: float = 0.5
) -> None:
    body = world.add_body(name=name, pos=pos)
    body.add_freejoint(name=f"{name}_free")
    body.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=half,
        mass=mass,
        friction=[friction, 0.005, 0.0001],
    )


# ---------------------------------------------------------------- registry <-> MJCF ------------


def test_built_in_robots_are_registered():
    assert set(BUILT_IN) <= set(ROBOTS)


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_registry_entry_matches_mjcf(name):
    spec = get_robot(name)
    model = load(name)
    actuators = tuple(model.actuator(i).name for i in range(model.nu))
    assert actuators == spec.ctrl_names
    assert len(spec.safe_ctrl) == model.nu
    lo, hi = model.actuator_ctrlrange.T
    assert np.all(lo <= spec.safe_ctrl) and np.all(np.asarray(spec.safe_ctrl) <= hi)
    kind, frame = (
        (mujoco.mjtObj.mjOBJ_SITE, spec.frame[5:])
        if spec.frame.startswith("site:")
        else (mujoco.mjtObj.mjOBJ_BODY, spec.frame)
    )
    assert mujoco.mj_name2id(model, kind, frame) >= 0, f"frame {spec.frame!r} not in {spec.mjcf}"


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_robot_files_bring_no_floor(name):
    # the scene builder adds the floor; a second plane would double every floor contact
    model = load(name)
    assert mujoco.mjtGeom.mjGEOM_PLANE not in set(model.geom_type)


def test_suction_variant_has_the_point_robots_body_and_drive():
    plain, suction = load("point_robot"), load("point_robot_suction")
    assert plain.opt.timestep == suction.opt.timestep == 0.05
    for field in ("geom_size", "geom_pos", "body_mass", "jnt_axis"):
        np.testing.assert_array_equal(getattr(plain, field), getattr(suction, field))
    np.testing.assert_array_equal(plain.actuator_gainprm[:2], suction.actuator_gainprm[:2])
    np.testing.assert_array_equal(plain.actuator_ctrlrange, suction.actuator_ctrlrange[:2])


# ---------------------------------------------------------------- point robot ------------------


def test_point_robot_tracks_velocity_without_touching_the_floor():
    model = with_world("point_robot", lambda world: None)
    data = mujoco.MjData(model)
    cmd = np.array([1.0, -0.5])
    fractions = []
    for _ in range(8):
        data.ctrl[:] = cmd
        mujoco.mj_step(model, data)
        fractions.append(data.qvel[:2] / cmd)
        assert data.ncon == 0
    # kv dt / m = 1.5: an implicit step leaves 1 / 2.5 of the velocity error
    np.testing.assert_allclose(fractions[0], 1 - 1 / 2.5, atol=1e-3)
    np.testing.assert_allclose(fractions[1], 1 - 1 / 2.5**2, atol=1e-3)
    np.testing.assert_allclose(fractions[7], 1.0, atol=1e-3)


def test_point_robot_commands_are_clamped_to_its_speed_limit():
    model = load("point_robot")
    data = mujoco.MjData(model)
    for _ in range(20):
        data.ctrl[:] = [10.0, -10.0]
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qvel, [1.5, -1.5], atol=1e-6)


# ---------------------------------------------------------------- suction ----------------------


def suction_scene() -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The thesis box (0.4 x 0.4 x 0.1 m, 1 kg) touching the robot's +x side, settled."""
    model = with_world(
        "point_robot_suction", lambda w: add_box(w, "box", [0.2, 0.2, 0.05], [0.4, 0.0, 0.05], 1.0)
    )
    data = mujoco.MjData(model)
    for _ in range(10):
        mujoco.mj_step(model, data)
    return model, data


def drive(model, data, velocity, suction, seconds) -> None:
    for _ in range(round(seconds / model.opt.timestep)):
        data.ctrl[:] = [*velocity, suction]
        mujoco.mj_step(model, data)


def box_gap(data) -> float:
    """Distance between the robot's disc and the box's near face along x (box on the +x side)."""
    return data.body("box").xpos[0] - 0.2 - (data.body("robot").xpos[0] + 0.2)


def test_suction_drags_the_box_when_the_robot_backs_away_and_turns():
    model, data = suction_scene()
    box0, robot0 = data.body("box").xpos.copy(), data.body("robot").xpos.copy()
    drive(model, data, (-0.5, 0.0), 1.0, 2.0)  # straight pull, about 1 m
    robot_moved = data.body("robot").xpos - robot0
    box_moved = data.body("box").xpos - box0
    assert robot_moved[0] < -0.8  # the box's friction (5-10 N) slows the servo by F / kv
    np.testing.assert_allclose(box_moved[:2], robot_moved[:2], atol=0.04)
    # attached: pressed into the soft contact (1.8 cm under steady suction), not torn off
    assert -0.03 < box_gap(data) < 0.01
    drive(model, data, (-0.5, 0.5), 1.0, 1.0)  # pull diagonally: the box swings behind
    drive(model, data, (0.0, 0.0), 1.0, 0.5)
    offset = data.body("box").xpos[:2] - data.body("robot").xpos[:2]
    # still attached: centre distance between face-on (0.4) and corner-on (0.2 + 0.2 * sqrt 2)
    assert 0.37 < np.linalg.norm(offset) < 0.5
    assert abs(data.body("box").xpos[2] - 0.05) < 0.01  # still lying on the floor


def test_without_suction_the_box_stays():
    model, data = suction_scene()
    box0 = data.body("box").xpos.copy()
    drive(model, data, (-0.5, 0.0), 0.0, 2.0)
    assert np.linalg.norm(data.body("box").xpos[:2] - box0[:2]) < 0.005
    assert box_gap(data) > 0.9


def test_suction_at_rest_holds_the_box_steadily():
    model, data = suction_scene()
    drive(model, data, (0.0, 0.0), 1.0, 1.0)
    assert -0.025 < box_gap(data) < 0.01
    assert np.linalg.norm(data.qvel) < 1e-2


# ---------------------------------------------------------------- diff drive -------------------


def body_frame_velocity(data) -> np.ndarray:
    """(forward, lateral, yaw rate) of the diff drive."""
    c, s = np.cos(data.qpos[2]), np.sin(data.qpos[2])
    vx, vy, wz = data.qvel
    return np.array([c * vx + s * vy, -s * vx + c * vy, wz])


def test_diff_drive_tracks_forward_speed_and_yaw_rate():
    model = with_world("diff_drive", lambda world: None)
    data = mujoco.MjData(model)
    for step in range(12):
        data.ctrl[:] = [1.0, 0.5, 0.0]
        mujoco.mj_step(model, data)
        v = body_frame_velocity(data)
        if step == 1:  # kv dt / inertia = 1.5: 1 - 1 / 2.5^2 of the command
            np.testing.assert_allclose(v[[0, 2]], [0.84, 0.42], atol=2e-3)
        assert data.ncon == 0
    np.testing.assert_allclose(body_frame_velocity(data)[[0, 2]], [1.0, 0.5], rtol=1e-3)


def test_diff_drive_turns_in_place_and_drives_along_its_new_heading():
    model = load("diff_drive")
    data = mujoco.MjData(model)
    steps = round((np.pi / 2) / 1.0 / model.opt.timestep)
    for i in range(steps + 20):  # 1 rad/s for ~pi/2, then let the servo settle
        data.ctrl[:] = [0.0, 1.0 if i < steps else 0.0, 0.0]
        mujoco.mj_step(model, data)
    heading = data.qpos[2]
    assert np.linalg.norm(data.qpos[:2]) < 1e-6
    start = data.qpos[:2].copy()
    for _ in range(40):
        data.ctrl[:] = [1.0, 0.0, 0.0]
        mujoco.mj_step(model, data)
    travel = data.qpos[:2] - start
    direction = np.array([np.cos(heading), np.sin(heading)])
    assert travel @ direction > 1.5
    assert abs(direction[0] * travel[1] - direction[1] * travel[0]) < 1e-6


def test_diff_drive_cannot_move_sideways():
    model = load("diff_drive")
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    lo, hi = model.actuator_ctrlrange.T
    for _ in range(400):
        # any command, the ignored lateral_grip channel included
        heading, start = data.qpos[2], data.qpos[:2].copy()
        data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
        step = data.qpos[:2] - start
        # each step's motion is along the heading it started with
        assert abs(-np.sin(heading) * step[0] + np.cos(heading) * step[1]) < 1e-3
    # a sustained 20 N sideways shove: the tyres creep at F / 4000 = 5 mm/s
    mujoco.mj_resetData(model, data)
    for _ in range(20):
        data.xfrc_applied[model.body("robot").id, 1] = 20.0
        mujoco.mj_step(model, data)
    assert 0 < data.qpos[1] < 0.01
    # the same shove on the omnidirectional robot moves it freely (for scale)
    omni = load("point_robot")
    odata = mujoco.MjData(omni)
    for _ in range(20):
        odata.xfrc_applied[omni.body("robot").id, 1] = 20.0
        mujoco.mj_step(omni, odata)
    assert odata.qpos[1] > 10 * data.qpos[1]


def test_diff_drive_lateral_grip_ignores_its_control():
    model = load("diff_drive")
    runs = []
    for grip in (-1.0, 0.0, 1.0):
        data = mujoco.MjData(model)
        for _ in range(20):
            data.ctrl[:] = [0.8, -0.7, grip]
            mujoco.mj_step(model, data)
        runs.append(data.qpos.copy())
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[1], runs[2])


# ---------------------------------------------------------------- panda ------------------------

PANDA_BASE = np.array([-0.45, 0.0, 1.125])


def panda_at_home(model) -> mujoco.MjData:
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    return data


def test_panda_home_pose_kinematics():
    model = load("panda")
    assert model.opt.timestep == 0.01
    data = panda_at_home(model)
    np.testing.assert_allclose(data.body("panda_link0").xpos, PANDA_BASE)
    # Franka's ready pose: TCP 0.307 m in front of and 0.487 m above the base flange, pointing
    # down (values from the DH table with the 0.1034 m TCP offset)
    grasp = data.site("grasp")
    np.testing.assert_allclose(grasp.xpos - PANDA_BASE, [0.307, 0.0, 0.487], atol=1e-3)
    assert grasp.xpos[2] > 1.0  # above the table top
    np.testing.assert_allclose(grasp.xmat.reshape(3, 3)[:, 2], [0, 0, -1], atol=1e-3)
    # fingertip sites measure the opening width; the home keyframe opens the hand fully
    width = np.linalg.norm(data.site("finger_left").xpos - data.site("finger_right").xpos)
    assert width == pytest.approx(0.08, abs=1e-9)
    np.testing.assert_allclose(
        (data.site("finger_left").xpos + data.site("finger_right").xpos) / 2, grasp.xpos, atol=1e-9
    )
    assert data.ncon == 0  # no self-contact


def test_panda_holds_still_and_tracks_joint_velocities():
    model = load("panda")
    data = panda_at_home(model)
    q0 = data.qpos.copy()
    for _ in range(100):  # zero command, gravity compensated: no sag
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qpos, q0, atol=1e-9)
    for joint in range(7):
        data = panda_at_home(model)
        fractions = []
        for _ in range(5):
            data.ctrl[joint] = 0.5
            mujoco.mj_step(model, data)
            fractions.append(data.qvel[joint] / 0.5)
        assert fractions[1] > 0.89 and fractions[4] > 0.99, (joint + 1, fractions)


def test_panda_gripper_mirrors_one_command():
    model = load("panda")
    data = panda_at_home(model)
    for target in (0.03, 0.0, 0.08):
        for _ in range(50):
            data.ctrl[7] = target
            mujoco.mj_step(model, data)
        left, right = (
            data.joint("panda_finger_joint1").qpos[0],
            data.joint("panda_finger_joint2").qpos[0],
        )
        assert left == pytest.approx(right, abs=1e-4)
        assert left + right == pytest.approx(target, abs=1e-3)


def test_panda_grasps_and_lifts_a_cube():
    base = load("panda")
    tcp = panda_at_home(base).site("grasp").xpos.copy()

    def cube_on_a_post(world):
        # a 5 cm cube centred between the open fingers, resting on a thin post
        world.add_geom(
            name="post",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.02, 0.02, 0.05],
            pos=[tcp[0], tcp[1], tcp[2] - 0.075],
        )
        add_box(world, "cube", [0.025] * 3, list(tcp), 0.1)

    model = with_world("panda", cube_on_a_post)
    data = panda_at_home(model)
    for _ in range(20):
        mujoco.mj_step(model, data)
    data.ctrl[7] = 0.0  # close
    for _ in range(30):
        mujoco.mj_step(model, data)
    l_gripper = np.linalg.norm(data.site("finger_left").xpos - data.site("finger_right").xpos)
    assert 0.047 < l_gripper < 0.05  # pads pressed on the 5 cm cube
    cube_z0 = data.body("cube").xpos[2]
    for joint, velocity in ((1, -0.5), (3, 0.5)):  # shoulder back, then elbow open
        for _ in range(40):
            data.ctrl[:7] = 0.0
            data.ctrl[joint] = velocity
            mujoco.mj_step(model, data)
        assert np.linalg.norm(data.body("cube").xpos - data.site("grasp").xpos) < 0.01
    assert data.body("cube").xpos[2] - cube_z0 > 0.1
    data.ctrl[:] = 0.0
    data.ctrl[7] = 0.08  # open: the cube drops
    for _ in range(30):
        mujoco.mj_step(model, data)
    assert data.site("grasp").xpos[2] - data.body("cube").xpos[2] > 0.05
