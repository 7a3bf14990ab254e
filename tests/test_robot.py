"""UR5e model and robot: FK against the DH table, twist control, failure reports, IK."""

from __future__ import annotations

import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pybullet
import pytest

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.robot import ur5e
from branch_gym.sim.robot.arm import UR5e
from branch_gym.sim.robot.camera_mount import CameraMountConfig, T_flange_camera
from branch_gym.sim.robot.config import InverseKinematicsError, MotionStatus, RobotConfig
from branch_gym.sim.robot.home import camera_pose_facing_branch, home_configuration
from branch_gym.sim.robot.kinematics import dh_forward_kinematics, dh_jacobian, rotation_log
from branch_gym.sim.robot.motion import (
    CameraMotion,
    camera_twist_from_world,
    orbit_camera_twist,
)
from branch_gym.sim.robot.ur5e_spec import JOINT_LIMIT_RAD

STEP_S = 1.0 / 60.0
BRANCH_POINT = np.array([0.0, 0.0, 0.275])


def _angle_between(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.linalg.norm(rotation_log(R_a.T @ R_b)))


@pytest.fixture(scope="module")
def bullet() -> Bullet:
    world = Bullet()
    yield world
    world.close()


@pytest.fixture
def robot(bullet: Bullet) -> UR5e:
    """A fresh robot at the home pose in an empty world."""
    bullet.reset()
    arm = UR5e(bullet)
    arm.set_joint_positions(home_configuration(arm, BRANCH_POINT))
    return arm


def _joint_twist(robot: UR5e, joint: int, rate_radps: float) -> np.ndarray:
    """The camera twist that moves one joint alone at ``rate_radps`` from the current pose."""
    return robot.camera_jacobian()[:, joint] * rate_radps


def _run(robot: UR5e, twist_of_pose, steps: int) -> tuple[MotionStatus, list[np.ndarray]]:
    """Apply a (pose-dependent) twist for up to ``steps`` control steps; stop at a failure."""
    poses = [robot.T_world_camera()]
    status = MotionStatus(True, "ok", robot.manipulability())
    for _ in range(steps):
        status = robot.apply_camera_twist(twist_of_pose(robot), STEP_S)
        if not status.ok:
            break
        poses.append(robot.T_world_camera())
    return status, poses


def test_pybullet_fk_matches_dh_table_on_random_joint_sets(robot: UR5e) -> None:
    rng = np.random.default_rng(2024)
    T_flange_cam = T_flange_camera(robot.config.mount)
    for q in rng.uniform(-math.pi, math.pi, size=(50, 6)):
        robot.set_joint_positions(q)
        T_expected = robot.T_world_base @ dh_forward_kinematics(q)
        T_flange = robot.T_world_flange()
        assert np.linalg.norm(T_flange[:3, 3] - T_expected[:3, 3]) < 1e-4
        assert _angle_between(T_flange[:3, :3], T_expected[:3, :3]) < 1e-4
        T_camera_expected = T_expected @ T_flange_cam
        T_camera = robot.T_world_camera()
        assert np.linalg.norm(T_camera[:3, 3] - T_camera_expected[:3, 3]) < 1e-4
        assert _angle_between(T_camera[:3, :3], T_camera_expected[:3, :3]) < 1e-4


def test_camera_jacobian_matches_dh_jacobian(robot: UR5e) -> None:
    rng = np.random.default_rng(5)
    R_world_base = robot.T_world_base[:3, :3]
    for q in rng.uniform(-math.pi, math.pi, size=(10, 6)):
        robot.set_joint_positions(q)
        _, J_base = dh_jacobian(q, T_flange_camera(robot.config.mount))
        R_camera_base = robot.T_world_camera()[:3, :3].T @ R_world_base
        J_expected = np.vstack([R_camera_base @ J_base[:3], R_camera_base @ J_base[3:]])
        np.testing.assert_allclose(robot.camera_jacobian(), J_expected, atol=1e-8)
        assert robot.manipulability() == pytest.approx(abs(np.linalg.det(J_base)), rel=1e-6)


def test_translation_twist_follows_a_straight_line(robot: UR5e) -> None:
    direction_camera = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    speed_mps, length_m = 0.025, 0.10
    twist = np.concatenate([speed_mps * direction_camera, np.zeros(3)])
    start = robot.T_world_camera()
    steps = round(length_m / speed_mps / STEP_S)
    status, poses = _run(robot, lambda _: twist, steps)
    assert status.ok, status
    direction_world = start[:3, :3] @ direction_camera
    offsets = np.array([T[:3, 3] - start[:3, 3] for T in poses])
    off_line = offsets - np.outer(offsets @ direction_world, direction_world)
    assert np.max(np.linalg.norm(off_line, axis=1)) < 1e-3
    assert np.linalg.norm(offsets[-1] - length_m * direction_world) < 1e-3
    assert _angle_between(poses[-1][:3, :3], start[:3, :3]) < 1e-3


def test_rotation_twist_keeps_the_camera_in_place(robot: UR5e) -> None:
    omega_camera = np.array([0.05, 0.2, 0.1])
    start = robot.T_world_camera()
    duration_s = 2.0
    status, poses = _run(robot, lambda _: np.concatenate([np.zeros(3), omega_camera]), 120)
    assert status.ok, status
    drift = [np.linalg.norm(T[:3, 3] - start[:3, 3]) for T in poses]
    assert max(drift) < 1e-3
    # Constant body rate: R(t) = R0 exp([omega t]); check the end orientation.
    rotvec = omega_camera * duration_s
    angle = np.linalg.norm(rotvec)
    axis = rotvec / angle
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R_step = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    assert _angle_between(poses[-1][:3, :3], start[:3, :3] @ R_step) < 2e-3


def test_substeps_equal_separate_control_steps(robot: UR5e) -> None:
    q_start = robot.q
    twist = np.array([0.01, -0.02, 0.005, 0.05, -0.02, 0.1])
    status = robot.apply_camera_twist(twist, 6 * STEP_S)
    assert status.ok and status.elapsed_s == pytest.approx(6 * STEP_S)
    T_once = robot.T_world_camera()
    robot.set_joint_positions(q_start)
    for _ in range(6):
        assert robot.apply_camera_twist(twist, STEP_S).ok
    np.testing.assert_allclose(robot.T_world_camera(), T_once, atol=1e-9)


def test_wrist_singularity_is_reported_not_crossed(robot: UR5e) -> None:
    q = robot.q
    q[4] = math.radians(-15.0)  # wrist 2 near 0: joint 6 nearly parallel to joint 4
    robot.set_joint_positions(q)
    assert robot.manipulability() > robot.config.manipulability_threshold
    status, _ = _run(robot, lambda arm: _joint_twist(arm, 4, 0.5), 200)
    assert status.reason == "singularity"
    assert robot.q[4] < 0.0  # stopped before aligning the wrist
    assert robot.manipulability() >= robot.config.manipulability_threshold
    # Exactly aligned: nothing moves.
    q[4] = 0.0
    robot.set_joint_positions(q)
    status = robot.apply_camera_twist(np.array([0.0, -0.025, 0, 0, 0, 0]), STEP_S)
    assert (status.ok, status.reason) == (False, "singularity")
    np.testing.assert_array_equal(robot.q, q)


def test_joint_limit_is_reported_and_backing_off_is_allowed(robot: UR5e) -> None:
    q = robot.q
    margin_rad = math.radians(robot.config.joint_limit_margin_deg)
    q[5] = JOINT_LIMIT_RAD - margin_rad - math.radians(1.0)
    robot.set_joint_positions(q)
    status, _ = _run(robot, lambda arm: _joint_twist(arm, 5, 0.5), 30)
    assert status.reason == "joint_limit"
    assert "wrist_3_joint" in status.detail
    assert robot.q[5] <= JOINT_LIMIT_RAD - margin_rad
    assert robot.apply_camera_twist(_joint_twist(robot, 5, -0.5), STEP_S).ok


def test_too_fast_twist_is_reported(robot: UR5e) -> None:
    q_before = robot.q
    status = robot.apply_camera_twist(np.array([0, 0, 0, 0, 0, 8.0]), STEP_S)
    assert (status.ok, status.reason) == (False, "joint_speed")
    np.testing.assert_array_equal(robot.q, q_before)


def test_box_in_the_path_gives_collision(robot: UR5e, bullet: Bullet) -> None:
    p = bullet.p
    camera_z = robot.T_world_camera()[2, 3]
    box_bottom_z = camera_z + 0.06
    box = p.createMultiBody(
        0,
        p.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.02, 0.02, 0.02]),
        basePosition=[*robot.T_world_camera()[:2, 3], box_bottom_z + 0.02],
    )
    robot.set_obstacles([box])
    up_twist = np.array([0.0, -0.025, 0.0, 0.0, 0.0, 0.0])  # image up = world up
    status, poses = _run(robot, lambda _: up_twist, 240)
    assert status.reason == "collision"
    assert "touches body" in status.detail
    assert robot.check_collision() is None  # the failed step was undone
    housing_top_z = robot.T_world_camera()[2, 3] + 0.5 * robot.config.mount.housing_size_m[1]
    assert box_bottom_z - 2e-3 < housing_top_z < box_bottom_z  # stopped right at the box
    assert len(poses) < 240


def test_going_below_the_ground_gives_collision(robot: UR5e) -> None:
    down_world = np.array([0.0, 0.0, -0.05])
    status, poses = _run(
        robot,
        lambda arm: camera_twist_from_world(arm.T_world_camera(), down_world, np.zeros(3)),
        600,
    )
    assert status.reason == "collision"
    assert "below the ground" in status.detail
    # The lowest link (wrist 2) hangs ~0.18 m under the camera: it stops just above the ground.
    assert 0.15 < poses[-1][2, 3] < 0.21
    unchecked = UR5e(robot.bullet, RobotConfig(ground_height_m=None), q=robot.q)
    assert unchecked.apply_camera_twist(np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0]), STEP_S).ok


def test_folding_the_elbow_gives_self_collision(robot: UR5e) -> None:
    q = robot.q
    q[2] = math.radians(-150.0)
    robot.set_joint_positions(q)
    assert robot.check_collision() is None
    status, _ = _run(robot, lambda arm: _joint_twist(arm, 2, -0.5), 120)
    assert status.reason == "collision"
    assert " touches " in status.detail and "body" not in status.detail  # link against link
    assert robot.check_collision() is None
    assert robot.q[2] < math.radians(-150.0)  # it did fold some way before stopping


def test_orbit_twist_turns_about_the_branch(robot: UR5e) -> None:
    yaw_rate_radps = 0.25
    steps = round(math.radians(45.0) / yaw_rate_radps / STEP_S)
    status, poses = _run(
        robot, lambda arm: orbit_camera_twist(arm.T_world_camera(), BRANCH_POINT, 0.25), steps
    )
    assert status.ok, status
    for T in poses:
        assert np.hypot(*(T[:2, 3] - BRANCH_POINT[:2])) == pytest.approx(0.2, abs=1e-3)
        assert T[2, 3] == pytest.approx(BRANCH_POINT[2], abs=1e-3)
    expected = camera_pose_facing_branch(BRANCH_POINT, 0.2, math.degrees(steps * STEP_S * 0.25))
    assert np.linalg.norm(poses[-1][:3, 3] - expected[:3, 3]) < 1e-3
    assert _angle_between(poses[-1][:3, :3], expected[:3, :3]) < 1e-3


def test_move_camera_to_goes_straight_and_arrives(robot: UR5e) -> None:
    start = robot.T_world_camera()
    target = camera_pose_facing_branch(BRANCH_POINT + np.array([0.03, 0.0, 0.05]), 0.2, 30.0)
    positions = []
    apply = robot.motion.apply_camera_twist

    def recording_apply(twist: np.ndarray, dt_s: float) -> MotionStatus:
        status = apply(twist, dt_s)
        positions.append(robot.T_world_camera()[:3, 3])
        return status

    robot.motion.apply_camera_twist = recording_apply  # type: ignore[method-assign]
    status = robot.move_camera_to(target, speed_mps=0.05)
    assert status.ok, status
    final = robot.T_world_camera()
    assert np.linalg.norm(final[:3, 3] - target[:3, 3]) <= robot.config.move_position_tolerance_m
    assert math.degrees(_angle_between(final[:3, :3], target[:3, :3])) <= 0.05
    line = target[:3, 3] - start[:3, 3]
    length_m = np.linalg.norm(line)
    offsets = np.array(positions) - start[:3, 3]
    off_line = offsets - np.outer(offsets @ line / length_m, line / length_m)
    assert np.max(np.linalg.norm(off_line, axis=1)) < 1e-3
    assert length_m / 0.05 < status.elapsed_s < length_m / 0.05 + 2.0


def test_ik_reaches_targets_near_home(robot: UR5e) -> None:
    rng = np.random.default_rng(11)
    q_home = robot.q
    for dq in rng.normal(0.0, 0.3, size=(20, 6)):
        robot.set_joint_positions(q_home + dq)
        target = robot.T_world_camera()
        q = robot.solve_ik(target, q_seed=q_home)
        robot.set_joint_positions(q)
        reached = robot.T_world_camera()
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 1e-3
        assert math.degrees(_angle_between(reached[:3, :3], target[:3, :3])) < 0.5


def test_ik_fails_clearly_on_unreachable_target(robot: UR5e) -> None:
    q_before = robot.q
    far_away = camera_pose_facing_branch(np.array([0.0, 1.5, 0.5]))
    with pytest.raises(InverseKinematicsError, match="out of reach"):
        robot.solve_ik(far_away)
    np.testing.assert_array_equal(robot.q, q_before)


def test_bad_inputs_raise_value_error(robot: UR5e) -> None:
    with pytest.raises(ValueError, match="twist_camera"):
        robot.apply_camera_twist(np.array([0, np.nan, 0, 0, 0, 0]), STEP_S)
    with pytest.raises(ValueError, match="twist_camera"):
        robot.apply_camera_twist(np.zeros(5), STEP_S)
    for dt_s in (0.0, -STEP_S, math.nan):
        with pytest.raises(ValueError, match="dt_s"):
            robot.apply_camera_twist(np.zeros(6), dt_s)
    with pytest.raises(ValueError, match="q must"):
        robot.set_joint_positions(np.full(6, np.inf))
    with pytest.raises(ValueError, match="T_world_camera_target"):
        robot.solve_ik(np.eye(3))
    with pytest.raises(ValueError, match="T_world_camera_target"):
        robot.move_camera_to(np.diag([1.0, 1.0, -1.0, 1.0]), speed_mps=0.05)
    with pytest.raises(ValueError, match="speed_mps"):
        robot.move_camera_to(robot.T_world_camera(), speed_mps=0.0)
    with pytest.raises(ValueError, match="control_time_step_s"):
        RobotConfig(control_time_step_s=0.0)
    with pytest.raises(ValueError, match="joint_limit_margin_deg"):
        RobotConfig(joint_limit_margin_deg=-1.0)
    with pytest.raises(ValueError, match="offset_m"):
        CameraMountConfig(forward_offset_m=math.nan)


def test_urdf_is_cached_outside_the_repository() -> None:
    path = ur5e.write_ur5e_urdf()
    assert path == ur5e.write_ur5e_urdf()  # same model, same cached file
    assert Path(tempfile.gettempdir()) in path.parents
    assert Path(__file__).resolve().parents[1] not in path.resolve().parents
    text = path.read_text()
    assert text.count('type="revolute"') == 6 and 'name="camera_optical"' in text
    other = ur5e.write_ur5e_urdf(CameraMountConfig(forward_offset_m=0.05))
    assert other != path


@pytest.mark.parametrize("angle_rad", [0.0, 1e-12, 1e-4, 0.3, 2.0, math.pi - 1e-3])
def test_rotation_exp_matches_scipy(angle_rad):
    from scipy.spatial.transform import Rotation

    from branch_gym.sim.robot.kinematics import rotation_exp

    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = rotation_exp(axis * angle_rad)
    np.testing.assert_allclose(R, Rotation.from_rotvec(axis * angle_rad).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)


def test_direct_joint_rates_equal_the_dls_where_undamped_and_decline_otherwise() -> None:
    from scipy.spatial.transform import Rotation

    config = RobotConfig()
    motion = CameraMotion(config, JOINT_LIMIT_RAD, None, None, None)  # solves only
    rng = np.random.default_rng(3)
    R_world_camera = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    twist = rng.normal(size=6) * 0.05
    U, _, Vt = np.linalg.svd(rng.normal(size=(6, 6)))
    well_conditioned = U @ np.diag([1.0, 0.8, 0.6, 0.5, 0.4, 0.3]) @ Vt
    direct = motion._undamped_joint_rates(well_conditioned, R_world_camera, twist)
    svd = CameraMotion(replace(config, dls_direct_solve=False), JOINT_LIMIT_RAD, None, None, None)
    dls, _ = svd._joint_rates(well_conditioned, R_world_camera, twist)
    np.testing.assert_allclose(direct, dls, rtol=1e-10, atol=1e-12)
    # Near the damping band the bound cannot prove the damping is zero; exactly singular fails.
    near_singular = U @ np.diag([1.0, 0.8, 0.6, 0.5, 0.4, 0.5 * config.damping_sigma_band]) @ Vt
    assert motion._undamped_joint_rates(near_singular, R_world_camera, twist) is None
    singular = well_conditioned.copy()
    singular[:, 2] = 0.0
    assert motion._undamped_joint_rates(singular, R_world_camera, twist) is None
