"""Tests for recon.geometry.triangulate: exactness, noise, lost tracks, validation."""

from __future__ import annotations

import numpy as np
import pytest

from recon.camera import CameraIntrinsics, make_pose, project_points, projection_matrix
from recon.geometry.triangulate import triangulate_points

INTRINSICS = CameraIntrinsics.from_fov()


def _look_at_pose(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4, 4) camera pose at ``eye`` whose optical axis points at ``target`` (world Z is up)."""
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return make_pose(np.stack([right, down, forward], axis=1), eye)


def _random_scene(
    rng: np.random.Generator, n_views: int, n_points: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cameras 0.2-0.4 m around a 5 cm cloud of points; returns poses, projections, points."""
    points = rng.uniform(-0.025, 0.025, size=(n_points, 3))
    poses = []
    for _ in range(n_views):
        direction = rng.normal(size=3)
        direction[2] *= 0.3
        direction /= np.linalg.norm(direction)
        poses.append(_look_at_pose(direction * rng.uniform(0.2, 0.4), rng.normal(0, 0.005, 3)))
    projections = np.stack([projection_matrix(INTRINSICS, pose) for pose in poses])
    return np.stack(poses), projections, points


def _project_all(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(M, N, 2) pixels of the points in every view."""
    return np.stack([project_points(points, pose, INTRINSICS)[0] for pose in poses])


def test_exact_on_noise_free_tracks() -> None:
    rng = np.random.default_rng(0)
    for _ in range(5):
        poses, projections, truth = _random_scene(rng, n_views=8, n_points=50)
        points, error_px = triangulate_points(_project_all(poses, truth), projections)
        assert np.max(np.linalg.norm(points - truth, axis=1)) < 1e-6
        assert np.max(error_px) < 1e-6


def test_exact_with_small_vertical_baseline() -> None:
    """The scanning geometry: 8 views 1 mm apart, points 0.2 m away."""
    poses = np.stack(
        [
            _look_at_pose(np.array([0.0, 0.0, 0.5 + k * 1e-3]), np.array([0.0, 1.0, 0.5]))
            for k in range(8)
        ]
    )
    projections = np.stack([projection_matrix(INTRINSICS, pose) for pose in poses])
    truth = np.array([[0.01, 0.2, 0.5], [-0.02, 0.25, 0.49], [0.0, 0.18, 0.51]])
    points, _ = triangulate_points(_project_all(poses, truth), projections)
    assert np.max(np.linalg.norm(points - truth, axis=1)) < 1e-6


def test_unbiased_under_pixel_noise() -> None:
    rng = np.random.default_rng(1)
    poses, projections, truth = _random_scene(rng, n_views=6, n_points=4000)
    noisy = _project_all(poses, truth) + rng.normal(0.0, 0.5, size=(6, 4000, 2))
    points, error_px = triangulate_points(noisy, projections)
    residual = points - truth
    mean, std = residual.mean(axis=0), residual.std(axis=0)
    assert np.all(std > 0.0)
    # The mean error is indistinguishable from zero: within 4 standard errors on every axis.
    assert np.all(np.abs(mean) < 4.0 * std / np.sqrt(len(residual)))
    assert np.median(error_px) < 2.0


def test_nan_views_are_skipped_for_that_point_only() -> None:
    rng = np.random.default_rng(2)
    poses, projections, truth = _random_scene(rng, n_views=8, n_points=20)
    pixels = _project_all(poses, truth) + rng.normal(0.0, 0.3, size=(8, 20, 2))
    lost = pixels.copy()
    lost[:3, 0] = np.nan  # point 0 lost in the three oldest views
    lost[5, 1] = np.nan  # point 1 lost in one middle view
    points, error_px = triangulate_points(lost, projections)
    subset_0, _ = triangulate_points(pixels[3:, :1], projections[3:])
    keep_1 = np.array([0, 1, 2, 3, 4, 6, 7])
    subset_1, _ = triangulate_points(pixels[keep_1, 1:2], projections[keep_1])
    # Equal up to the conditioning shift (the world origin moves to the mean camera centre of the
    # views given), which changes the last digits only: 0.1 um against ~1 mm of noise-induced error.
    np.testing.assert_allclose(points[0], subset_0[0], rtol=0.0, atol=1e-7)
    np.testing.assert_allclose(points[1], subset_1[0], rtol=0.0, atol=1e-7)
    # The untouched points do not move; the lost views did matter for points 0 and 1.
    full, _ = triangulate_points(pixels, projections)
    assert np.all(np.linalg.norm(points[:2] - full[:2], axis=1) > 1e-6)
    np.testing.assert_allclose(points[2:], full[2:], atol=1e-9)
    assert np.all(np.isfinite(error_px))


def test_fewer_than_two_valid_views_gives_nan_and_inf() -> None:
    rng = np.random.default_rng(3)
    poses, projections, truth = _random_scene(rng, n_views=4, n_points=3)
    pixels = _project_all(poses, truth)
    pixels[1:, 0] = np.nan  # one view left
    pixels[:, 1] = np.nan  # no view left
    points, error_px = triangulate_points(pixels, projections)
    assert np.all(np.isnan(points[:2])) and np.all(np.isinf(error_px[:2]))
    np.testing.assert_allclose(points[2], truth[2], atol=1e-6)


def test_no_baseline_gives_nan_not_an_arbitrary_point() -> None:
    """Views from one optical centre (pure rotation) cannot fix the depth."""
    eye = np.array([0.0, 0.0, 0.5])
    poses = np.stack([_look_at_pose(eye, np.array([x, 1.0, 0.5])) for x in (-0.05, 0.0, 0.05)])
    projections = np.stack([projection_matrix(INTRINSICS, pose) for pose in poses])
    truth = np.array([[0.0, 0.2, 0.5], [0.01, 0.3, 0.52]])
    points, error_px = triangulate_points(_project_all(poses, truth), projections)
    assert np.all(np.isnan(points)) and np.all(np.isinf(error_px))


def test_point_behind_a_camera_gets_infinite_error() -> None:
    poses = np.stack(
        [_look_at_pose(np.array([x, 0.0, 0.5]), np.array([x, 1.0, 0.5])) for x in (0.0, 0.01)]
    )
    projections = np.stack([projection_matrix(INTRINSICS, pose) for pose in poses])
    # Pixels consistent with a point 0.2 m *behind* both cameras (mirror image through the centre).
    behind = np.array([[0.005, -0.2, 0.51]])
    mirrored = 2.0 * poses[:, :3, 3][:, None, :] - behind[None]  # reflect through each centre
    pixels = np.stack([project_points(mirrored[i], poses[i], INTRINSICS)[0] for i in range(2)])
    points, error_px = triangulate_points(pixels, projections)
    np.testing.assert_allclose(points[0], behind[0], atol=1e-6)
    assert np.isinf(error_px[0])


def test_reprojection_error_reports_the_worst_view() -> None:
    rng = np.random.default_rng(4)
    poses, projections, truth = _random_scene(rng, n_views=8, n_points=10)
    pixels = _project_all(poses, truth)
    pixels[4, 3, 0] += 30.0  # one gross outlier in one view
    _, error_px = triangulate_points(pixels, projections)
    assert error_px[3] > 5.0
    assert np.all(np.delete(error_px, 3) < 1e-6)


def test_empty_input_returns_empty_arrays() -> None:
    rng = np.random.default_rng(5)
    _, projections, _ = _random_scene(rng, n_views=3, n_points=1)
    points, error_px = triangulate_points(np.zeros((3, 0, 2)), projections)
    assert points.shape == (0, 3) and error_px.shape == (0,)


@pytest.mark.parametrize(
    ("pixels_shape", "projections_shape", "message"),
    [
        ((8, 5), (8, 3, 4), "pixels"),
        ((8, 5, 3), (8, 3, 4), "pixels"),
        ((8, 5, 2), (8, 4, 4), "projections"),
        ((8, 5, 2), (7, 3, 4), "views"),
        ((1, 5, 2), (1, 3, 4), "at least 2"),
    ],
)
def test_bad_shapes_raise(
    pixels_shape: tuple[int, ...], projections_shape: tuple[int, ...], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        triangulate_points(np.zeros(pixels_shape), np.ones(projections_shape))


def test_non_finite_projection_raises() -> None:
    rng = np.random.default_rng(6)
    poses, projections, truth = _random_scene(rng, n_views=3, n_points=2)
    projections[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        triangulate_points(_project_all(poses, truth), projections)
