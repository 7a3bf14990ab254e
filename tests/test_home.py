"""Home pose and base placement: the whole scan range is reachable and can be moved through."""

from __future__ import annotations

import math

import numpy as np
import pybullet
import pytest

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.robot.arm import UR5e
from branch_gym.sim.robot.home import (
    SCAN_END_HEIGHT_M,
    SCAN_START_HEIGHT_M,
    Z_TARGET_M,
    BasePlacement,
    camera_pose_facing_branch,
    elbow_up,
    home_configuration,
    sweep_scan_workspace,
)
from branch_gym.sim.robot.motion import camera_twist_from_world, orbit_camera_twist

STEP_S = 1.0 / 60.0
SCAN_SPEED_MPS = 0.025  # reference.md "Scan": sim speed 2.5 cm/s
ORBIT_RATE_RADPS = 0.25  # 5 cm/s along the 0.2 m circle
MAX_ROTATION_DEG = 45.0  # paper Table I: rotations up to 45 deg
BRANCH_RADIUS_M = 0.0075  # thickest primary (reference.md: 3-7.5 mm)
# The placement must keep manipulability this many thresholds away from singular; measured:
# >= 0.055 over the grid below (0.077 without the leaning branches), threshold 0.01.
MANIPULABILITY_MARGIN = 5.0


class World:
    """A robot, the ground and a vertical primary branch that can be moved."""

    def __init__(self, bullet: Bullet) -> None:
        bullet.reset()
        p = bullet.p
        self.p = p
        self.ground = p.createMultiBody(0, p.createCollisionShape(pybullet.GEOM_PLANE))
        shape = p.createCollisionShape(pybullet.GEOM_CYLINDER, radius=BRANCH_RADIUS_M, height=1.0)
        self.branch = p.createMultiBody(0, shape, basePosition=[0.0, 0.0, 0.5])
        self.robot = UR5e(bullet)
        self.robot.set_obstacles([self.branch, self.ground])

    def place_branch(self, x_m: float, y_m: float) -> None:
        self.p.resetBasePositionAndOrientation(self.branch, [x_m, y_m, 0.5], [0, 0, 0, 1])


@pytest.fixture(scope="module")
def bullet() -> Bullet:
    world = Bullet()
    yield world
    world.close()


@pytest.fixture
def world(bullet: Bullet) -> World:
    return World(bullet)


def test_home_pose_faces_the_branch_level_and_upright(world: World) -> None:
    robot = world.robot
    point = np.array([0.0, 0.0, SCAN_START_HEIGHT_M])
    q = home_configuration(robot)
    robot.set_joint_positions(q)
    T = robot.T_world_camera()
    np.testing.assert_allclose(T[:3, 3], point - np.array([0.0, Z_TARGET_M, 0.0]), atol=1e-3)
    assert math.degrees(math.acos(T[:3, 2] @ [0.0, 1.0, 0.0])) < 0.5  # optical axis along +y
    assert math.degrees(math.acos(T[:3, 1] @ [0.0, 0.0, -1.0])) < 0.5  # image up = world up
    assert elbow_up(robot, q)
    assert abs(math.degrees(q[4]) + 90.0) < 1.0  # wrist 2 at its most comfortable
    assert robot.manipulability() > MANIPULABILITY_MARGIN * robot.config.manipulability_threshold
    assert robot.check_collision() is None


def test_home_for_another_branch_point(world: World) -> None:
    robot = world.robot
    point = np.array([0.06, -0.02, 0.32])
    robot.set_joint_positions(home_configuration(robot, point, yaw_about_branch_deg=20.0))
    expected = camera_pose_facing_branch(point, Z_TARGET_M, 20.0)
    np.testing.assert_allclose(robot.T_world_camera(), expected, atol=1e-3)


def test_camera_pose_facing_branch_geometry() -> None:
    point = np.array([0.1, 0.02, 0.5])
    T = camera_pose_facing_branch(point, 0.2, 90.0)
    np.testing.assert_allclose(
        T[:3, 3], point + np.array([0.2, 0.0, 0.0]), atol=1e-12
    )  # moved to +x
    np.testing.assert_allclose(T[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)  # looking back at it
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="branch_point_world"):
        camera_pose_facing_branch(np.array([0.0, np.nan, 0.3]))
    with pytest.raises(ValueError, match="standoff_m"):
        camera_pose_facing_branch(point, standoff_m=0.0)


def test_base_placement_validation() -> None:
    assert BasePlacement().T_world_base[:3, 3] == pytest.approx([0.0, -0.80, 0.20])
    with pytest.raises(ValueError, match="position_m"):
        BasePlacement(position_m=(0.0, -0.8, -0.1))
    with pytest.raises(ValueError, match="home_seed_q_deg"):
        BasePlacement(home_seed_q_deg=(0.0,) * 5)


def test_whole_scan_range_is_reachable_away_from_singularities(world: World) -> None:
    heights_m = np.linspace(SCAN_START_HEIGHT_M, SCAN_END_HEIGHT_M, 6)
    angles_deg = np.linspace(-MAX_ROTATION_DEG, MAX_ROTATION_DEG, 5)
    # Branch offsets: x +-0.10 m (top-end offset), y +-0.02 m (placement jitter) and +-0.10 m
    # (a branch leaning toward or away from the camera, reference.md "Simulated world").
    offsets_m = [(x, y) for x in (-0.10, 0.0, 0.10) for y in (-0.10, -0.02, 0.02, 0.10)]
    report = sweep_scan_workspace(
        world.robot, heights_m, angles_deg, offsets_m, place_branch=world.place_branch
    )
    assert report.failures == []
    assert report.n_poses == len(offsets_m) * len(angles_deg) * (len(heights_m) + 4)
    threshold = world.robot.config.manipulability_threshold
    assert report.min_manipulability > MANIPULABILITY_MARGIN * threshold
    assert report.min_joint_margin_deg > 90.0


def _run_twist(robot: UR5e, twist_of_robot, duration_s: float) -> None:
    for step in range(round(duration_s / STEP_S)):
        status = robot.apply_camera_twist(twist_of_robot(robot), STEP_S)
        assert status.ok, f"step {step}: {status}"


def _orbit(robot: UR5e, pivot: np.ndarray, angle_deg: float) -> None:
    steps = math.ceil(math.radians(abs(angle_deg)) / ORBIT_RATE_RADPS / STEP_S)
    rate = math.radians(angle_deg) / (steps * STEP_S)  # exactly angle_deg in whole steps
    _run_twist(
        robot, lambda arm: orbit_camera_twist(arm.T_world_camera(), pivot, rate), steps * STEP_S
    )


def _climb(robot: UR5e, velocity_world_mps: np.ndarray, duration_s: float) -> None:
    def twist(arm: UR5e) -> np.ndarray:
        return camera_twist_from_world(arm.T_world_camera(), velocity_world_mps, np.zeros(3))

    _run_twist(robot, twist, duration_s)


@pytest.mark.parametrize("offset_m", [(0.10, 0.02), (-0.10, -0.02)])
def test_scan_motions_never_fail(world: World, offset_m: tuple[float, float]) -> None:
    """Rotate +-45 deg at the bottom, climb at 2.5 cm/s, rotate at the top, come down rotated."""
    robot = world.robot
    world.place_branch(*offset_m)
    bottom = np.array([*offset_m, SCAN_START_HEIGHT_M])
    top = np.array([*offset_m, SCAN_END_HEIGHT_M])
    robot.set_joint_positions(home_configuration(robot, bottom))
    climb_s = (SCAN_END_HEIGHT_M - SCAN_START_HEIGHT_M) / SCAN_SPEED_MPS
    up = np.array([0.0, 0.0, SCAN_SPEED_MPS])
    for angle_deg in (MAX_ROTATION_DEG, -2 * MAX_ROTATION_DEG, MAX_ROTATION_DEG):
        _orbit(robot, bottom, angle_deg)
    _climb(robot, up, climb_s)
    for angle_deg in (MAX_ROTATION_DEG, -2 * MAX_ROTATION_DEG):
        _orbit(robot, top, angle_deg)
    _climb(robot, -up, climb_s)  # down again, rotated by -45 deg
    expected = camera_pose_facing_branch(bottom, Z_TARGET_M, -MAX_ROTATION_DEG)
    np.testing.assert_allclose(robot.T_world_camera(), expected, atol=2e-3)
