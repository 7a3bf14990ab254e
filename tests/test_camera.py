"""Tests for recon.camera: intrinsics, poses, projection and unprojection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.camera import (
    CameraIntrinsics,
    check_pose,
    invert_pose,
    make_pose,
    pixel_rays_camera,
    project_points,
    projection_matrix,
    transform_points,
    unproject_pixels,
)

INTRINSICS = CameraIntrinsics.from_fov()


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    rotation = Rotation.random(random_state=rng).as_matrix()
    return make_pose(rotation, rng.uniform(-1.0, 1.0, 3))


def test_from_fov_matches_the_authors_camera() -> None:
    """320x240 at 42 deg horizontal FoV: fx = fy ~ 416.8 px, principal point (160, 120)."""
    assert INTRINSICS.fx == pytest.approx(416.8, abs=0.05)
    assert INTRINSICS.fy == INTRINSICS.fx
    assert (INTRINSICS.cx, INTRINSICS.cy) == (160.0, 120.0)
    assert (INTRINSICS.width, INTRINSICS.height) == (320, 240)
    # The horizontal FoV is recovered from fx.
    assert 2.0 * math.degrees(math.atan(160.0 / INTRINSICS.fx)) == pytest.approx(42.0)
    # Vertical strip at 0.2 m: 0.2 * 240 / 416.8 = 0.115 m.
    assert INTRINSICS.vertical_fov_length_m(0.2) == pytest.approx(0.2 * 240 / INTRINSICS.fy)


def test_intrinsics_validation_and_matrix_round_trip() -> None:
    K = INTRINSICS.K
    assert K.shape == (3, 3) and K[0, 0] == INTRINSICS.fx and K[1, 2] == INTRINSICS.cy
    assert CameraIntrinsics.from_matrix(K, 320, 240) == INTRINSICS
    with pytest.raises(ValueError, match="image size"):
        CameraIntrinsics(0, 240, 400.0, 400.0, 160.0, 120.0)
    with pytest.raises(ValueError, match="fx"):
        CameraIntrinsics(320, 240, float("nan"), 400.0, 160.0, 120.0)
    with pytest.raises(ValueError, match="focal"):
        CameraIntrinsics(320, 240, -400.0, 400.0, 160.0, 120.0)
    with pytest.raises(ValueError, match="hfov_deg"):
        CameraIntrinsics.from_fov(hfov_deg=180.0)
    with pytest.raises(ValueError, match="K must"):
        CameraIntrinsics.from_matrix(np.eye(4), 320, 240)


def test_project_known_point() -> None:
    """A point 0.2 m ahead and 1 cm right of the optical axis, identity pose."""
    pixels, depth = project_points(np.array([[0.01, -0.02, 0.2]]), np.eye(4), INTRINSICS)
    np.testing.assert_allclose(
        pixels[0], [160.0 + INTRINSICS.fx * 0.05, 120.0 - INTRINSICS.fy * 0.1]
    )
    assert depth[0] == pytest.approx(0.2)


def test_points_behind_the_camera_project_to_nan() -> None:
    pixels, depth = project_points(
        np.array([[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]]), np.eye(4), INTRINSICS
    )
    assert np.all(np.isnan(pixels[0])) and np.all(np.isfinite(pixels[1]))
    assert depth[0] == pytest.approx(-0.5)


def test_project_unproject_round_trip() -> None:
    rng = np.random.default_rng(0)
    for _ in range(5):
        pose = _random_pose(rng)
        pixels = rng.uniform([0.0, 0.0], [319.0, 239.0], size=(50, 2))
        depth = rng.uniform(0.1, 2.0, size=50)
        points = unproject_pixels(pixels, depth, pose, INTRINSICS)
        back, back_depth = project_points(points, pose, INTRINSICS)
        np.testing.assert_allclose(back, pixels, atol=1e-9)
        np.testing.assert_allclose(back_depth, depth, atol=1e-12)


def test_pixel_rays_point_at_the_unprojected_points() -> None:
    rng = np.random.default_rng(1)
    pixels = rng.uniform(0.0, 239.0, size=(20, 2))
    rays = pixel_rays_camera(pixels, INTRINSICS)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    points = unproject_pixels(pixels, np.ones(20), np.eye(4), INTRINSICS)
    np.testing.assert_allclose(rays, points / np.linalg.norm(points, axis=1, keepdims=True))


def test_projection_matrix_agrees_with_project_points() -> None:
    rng = np.random.default_rng(2)
    pose = _random_pose(rng)
    camera_points = np.column_stack([rng.uniform(-0.1, 0.1, (30, 2)), rng.uniform(0.1, 1.0, 30)])
    world_points = transform_points(pose, camera_points)
    P = projection_matrix(INTRINSICS, pose)
    homogeneous = np.column_stack([world_points, np.ones(30)]) @ P.T
    expected, depth = project_points(world_points, pose, INTRINSICS)
    np.testing.assert_allclose(homogeneous[:, :2] / homogeneous[:, 2:], expected, atol=1e-9)
    np.testing.assert_allclose(homogeneous[:, 2], depth, atol=1e-12)  # K's last row: P X = z


def test_pose_helpers() -> None:
    rng = np.random.default_rng(3)
    pose = _random_pose(rng)
    np.testing.assert_allclose(invert_pose(pose) @ pose, np.eye(4), atol=1e-12)
    points = rng.normal(size=(10, 3))
    np.testing.assert_allclose(
        transform_points(invert_pose(pose), transform_points(pose, points)), points, atol=1e-12
    )
    assert check_pose(pose) is not None


def test_in_image_bounds_and_margin() -> None:
    pixels = np.array(
        [[0.0, 0.0], [-0.5, -0.5], [-0.6, 10.0], [319.5, 239.5], [319.6, 10.0], [np.nan, 5.0]]
    )
    np.testing.assert_array_equal(
        INTRINSICS.in_image(pixels), [True, True, False, True, False, False]
    )
    np.testing.assert_array_equal(
        INTRINSICS.in_image(np.array([[9.0, 100.0], [9.6, 100.0], [309.4, 100.0]]), margin_px=10.0),
        [False, True, True],
    )
    assert INTRINSICS.in_image(np.zeros((4, 3, 2))).shape == (4, 3)


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        (np.eye(3), "shape"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "rotation"),  # a reflection
        (np.diag([2.0, 1.0, 1.0, 1.0]), "rotation"),  # a scaling
        (make_pose(np.eye(3), np.zeros(3)) + np.array([[0, 0, 0, 0]] * 3 + [[0, 0, 1, 0]]), "row"),
    ],
)
def test_check_pose_rejects_bad_transforms(pose: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_pose(pose)
