"""The follow controller (paper V) on synthetic straight branches, without the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from branch_gym.control import FollowControllerConfig, PrimaryBranchController
from recon.camera import CameraIntrinsics, make_pose
from recon.model import BranchModel

# Camera looking along world +y, image up = world +z (OpenCV axes as columns).
R_LEVEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _straight_branch(top_offset: tuple[float, float]) -> BranchModel:
    z = np.linspace(0.0, 1.0, 201)
    points = np.stack([top_offset[0] * z, top_offset[1] * z, z], axis=1)
    return BranchModel(points, np.full(len(z), 0.005))


def _integrate(T: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """Move a camera pose by a camera-frame twist (first order, exact for the translation)."""
    R = T[:3, :3]
    w = R @ twist[3:]
    angle = np.linalg.norm(w) * dt
    R_step = np.eye(3)
    if angle > 0:
        k = w / np.linalg.norm(w)
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R_step = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    return make_pose(R_step @ R, T[:3, 3] + R @ twist[:3] * dt)


def _run(branch: BranchModel, start: np.ndarray, travel_m: float):
    """Drive a kinematic camera with the controller; return its final pose and the error traces."""
    controller = PrimaryBranchController(FollowControllerConfig(), CameraIntrinsics.from_fov())
    T = make_pose(R_LEVEL, start)
    dt = 1.0 / 60.0
    pixel_errors, depth_errors = [], []
    for _ in range(int(travel_m / controller.config.speed_mps / dt)):
        command = controller.command(branch, T)
        assert np.linalg.norm(command.twist_camera[:3]) == pytest.approx(
            controller.config.speed_mps
        )
        T = _integrate(T, command.twist_camera, dt)
        pixel_errors.append(command.pixel_error)
        depth_errors.append(command.depth_error)
    return T, np.array(pixel_errors), np.array(depth_errors)


@pytest.mark.parametrize("top_offset", [(0.0, 0.0), (0.10, 0.0), (-0.08, 0.06)])
def test_keeps_straight_branch_centred_at_z_target(top_offset) -> None:
    branch = _straight_branch(top_offset)
    start = np.array([top_offset[0] * 0.3, -0.20 + top_offset[1] * 0.3, 0.3])
    T, pixel_errors, depth_errors = _run(branch, start, travel_m=0.4)
    # Normalised errors: 0.0125 = 2 px of the half width; 0.005 = 1 mm of z_target.
    assert np.max(np.abs(pixel_errors)) < 0.0125
    assert np.max(np.abs(depth_errors)) < 0.005
    assert T[2, 3] > 0.65  # it climbed along the branch
    assert np.allclose(T[:3, 1], [0, 0, -1], atol=1e-3)  # and stayed level


def test_converges_from_an_offset_start() -> None:
    branch = _straight_branch((0.05, 0.03))
    start = np.array([0.03 + 0.05 * 0.3, -0.23 + 0.03 * 0.3, 0.3])  # 3 cm right, 3 cm too far
    _, pixel_errors, depth_errors = _run(branch, start, travel_m=0.4)
    # Proportional control on normalised errors decays ~exp(-k speed t / z_target).
    assert abs(pixel_errors[-1]) < 0.1 * abs(pixel_errors[0])
    assert abs(depth_errors[-1]) < 0.2 * abs(depth_errors[0])


def test_without_model_moves_straight_up() -> None:
    controller = PrimaryBranchController()
    T = make_pose(R_LEVEL, np.array([0.0, -0.2, 0.3]))
    command = controller.command(None, T)
    v_world = T[:3, :3] @ command.twist_camera[:3]
    np.testing.assert_allclose(v_world, [0, 0, controller.config.speed_mps], atol=1e-12)
    assert command.look_at_world is None
    # A model entirely out of view counts as no model.
    far = BranchModel(np.array([[5.0, 5.0, 0.0], [5.0, 5.0, 1.0]]), np.array([0.005, 0.005]))
    assert controller.command(far, T).look_at_world is None


def test_bad_config_raises() -> None:
    with pytest.raises(ValueError, match="speed_mps"):
        FollowControllerConfig(speed_mps=0.0)
    with pytest.raises(ValueError, match="k_u"):
        FollowControllerConfig(k_u=float("nan"))
