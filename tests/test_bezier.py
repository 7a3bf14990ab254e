"""Tests for recon.geometry (bezier, bezier_fit): evaluation, fitting, closest points, RANSAC."""

from __future__ import annotations

import numpy as np
import pytest

from recon.geometry.bezier import CubicBezier
from recon.geometry.bezier_fit import RansacFit, chord_length_params, fit_bezier, ransac_fit_bezier

CURVE_2D = CubicBezier(np.array([[150.0, 230.0], [190.0, 160.0], [120.0, 80.0], [170.0, 10.0]]))
CURVE_3D = CubicBezier(
    np.array([[0.0, 0.0, 0.2], [0.03, -0.01, 0.45], [-0.02, 0.04, 0.7], [0.05, 0.02, 1.0]])
)


def _dense(curve: CubicBezier, n: int = 200_001) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.0, n)
    return t, curve(t)


@pytest.mark.parametrize("curve", [CURVE_2D, CURVE_3D], ids=["2d", "3d"])
def test_fit_recovers_control_points_from_exact_samples(curve: CubicBezier) -> None:
    t = np.sort(np.random.default_rng(0).uniform(0.0, 1.0, 60))
    fitted = fit_bezier(curve(t), t=t)
    np.testing.assert_allclose(fitted.control_points, curve.control_points, atol=1e-8)


def test_fit_with_reparametrisation_approaches_the_true_curve() -> None:
    t = np.linspace(0.0, 1.0, 80) ** 1.5  # uneven speed: chord params differ from the truth
    points = CURVE_2D(t)
    plain = fit_bezier(points)
    refined = fit_bezier(points, reparametrize_iterations=30)
    _, truth = _dense(CURVE_2D, 2001)
    plain_err = np.abs(plain.closest_params(truth)[1]).max()
    refined_err = np.abs(refined.closest_params(truth)[1]).max()
    assert refined_err < 0.05  # pixels, on a ~240 px long curve
    assert refined_err < plain_err


def test_fit_passes_near_noisy_points_of_a_straight_line() -> None:
    rng = np.random.default_rng(1)
    v = np.linspace(220.0, 20.0, 200)
    points = np.stack([100.0 + 0.2 * v, v], axis=1) + rng.normal(0.0, 0.5, (200, 2))
    curve = fit_bezier(points)
    assert curve.max_bend_angle_deg() < 3.0
    assert np.median(curve.closest_params(points)[1]) < 0.6


@pytest.mark.parametrize("curve", [CURVE_2D, CURVE_3D], ids=["2d", "3d"])
def test_tangent_and_second_derivative_match_finite_differences(curve: CubicBezier) -> None:
    t = np.linspace(0.01, 0.99, 25)
    h = 1e-6
    fd_tangent = (curve(t + h) - curve(t - h)) / (2 * h)
    np.testing.assert_allclose(curve.tangent(t), fd_tangent, rtol=1e-6, atol=1e-6)
    fd_second = (curve.tangent(t + h) - curve.tangent(t - h)) / (2 * h)
    np.testing.assert_allclose(curve.second_derivative(t), fd_second, rtol=1e-5, atol=1e-5)


def test_length_of_a_straight_segment_is_exact() -> None:
    line = CubicBezier(np.array([[0.0, 0.0], [1.0, 2.0], [2.0, 4.0], [3.0, 6.0]]))
    assert line.length() == pytest.approx(np.hypot(3.0, 6.0), rel=1e-12)
    assert line.max_bend_angle_deg() == pytest.approx(0.0, abs=1e-5)


@pytest.mark.parametrize("spacing", [5.0, 30.0])
def test_resample_by_arclength_is_uniform(spacing: float) -> None:
    points, t = CURVE_2D.resample_by_arclength(spacing)
    np.testing.assert_allclose(points[0], CURVE_2D.control_points[0], atol=1e-9)
    np.testing.assert_allclose(points[-1], CURVE_2D.control_points[-1], atol=1e-9)
    assert np.all(np.diff(t) > 0.0)
    # Arc length between consecutive samples, from a dense polyline.
    t_dense, dense = _dense(CURVE_2D)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    gaps = np.diff(np.interp(t, t_dense, cum))
    assert gaps.max() <= spacing * 1.001
    np.testing.assert_allclose(gaps, gaps.mean(), rtol=0.01)
    assert gaps.sum() == pytest.approx(CURVE_2D.length(), rel=1e-4)


def test_resample_by_count_gives_requested_points() -> None:
    points, t = CURVE_3D.resample_by_count(7)
    assert points.shape == (7, 3) and t.shape == (7,)
    np.testing.assert_allclose(points, CURVE_3D(t))


@pytest.mark.parametrize("curve", [CURVE_2D, CURVE_3D], ids=["2d", "3d"])
def test_closest_params_matches_brute_force(curve: CubicBezier) -> None:
    rng = np.random.default_rng(2)
    scale = np.ptp(curve.control_points, axis=0).max()
    near = curve(rng.uniform(0, 1, 300)) + rng.normal(0.0, 0.02 * scale, (300, curve.dim))
    far = curve.control_points.mean(axis=0) + rng.uniform(-scale, scale, (300, curve.dim))
    t_dense, dense = _dense(curve)
    for points, tolerance in ((near, 1e-6 * scale), (far, 1e-4 * scale)):
        t, dist = curve.closest_params(points)
        d2 = ((points[:, None, :] - dense[None, ::50, :]) ** 2).sum(axis=2)
        coarse = np.argmin(d2, axis=1) * 50
        # Refine the brute-force search around its coarse minimum.
        window = np.clip(coarse[:, None] + np.arange(-60, 61)[None, :], 0, len(t_dense) - 1)
        brute = np.linalg.norm(dense[window] - points[:, None, :], axis=2).min(axis=1)
        assert np.all(dist <= brute + 1e-9 * scale)  # the dense search only overestimates
        np.testing.assert_allclose(dist, brute, atol=tolerance)
        np.testing.assert_allclose(curve(t), points, atol=dist.max() + 1e-9)
        assert np.all((t >= 0.0) & (t <= 1.0))


def test_closest_params_clips_to_the_curve_ends() -> None:
    beyond = np.array([[150.0, 300.0], [170.0, -50.0]])
    t, dist = CURVE_2D.closest_params(beyond)
    np.testing.assert_allclose(t, [0.0, 1.0])
    np.testing.assert_allclose(dist, [70.0, 60.0])


def test_max_bend_of_a_quarter_circle_is_ninety_degrees() -> None:
    k = 0.5522847498  # standard cubic approximation of a quarter circle
    arc = CubicBezier(np.array([[1.0, 0.0], [1.0, k], [k, 1.0], [0.0, 1.0]]))
    assert arc.max_bend_angle_deg() == pytest.approx(90.0, abs=0.5)


def test_reversed_traverses_backwards() -> None:
    t = np.linspace(0.0, 1.0, 11)
    np.testing.assert_allclose(CURVE_3D.reversed()(t), CURVE_3D(1.0 - t), atol=1e-12)


def test_chord_length_params() -> None:
    points = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [3.0, 9.0]])
    np.testing.assert_allclose(chord_length_params(points), [0.0, 0.5, 0.5, 1.0])


def _noisy_branch(
    rng: np.random.Generator, outlier_fraction: float
) -> tuple[np.ndarray, np.ndarray]:
    """Points along CURVE_3D (ordered) with gross outliers scattered through the sequence."""
    n = 100
    points = CURVE_3D(np.linspace(0.0, 1.0, n)) + rng.normal(0.0, 0.002, (n, 3))
    outlier = rng.random(n) < outlier_fraction
    points[outlier] += rng.uniform(-0.3, 0.3, (outlier.sum(), 3)) + np.array([0.15, 0.15, 0.0])
    return points, outlier


def test_ransac_recovers_curve_despite_thirty_percent_outliers() -> None:
    rng = np.random.default_rng(3)
    points, outlier = _noisy_branch(rng, 0.3)
    fit = ransac_fit_bezier(points, inlier_threshold=0.03, min_inlier_fraction=0.5, rng=rng)
    assert isinstance(fit, RansacFit)
    _, truth = _dense(CURVE_3D, 501)
    assert fit.curve.closest_params(truth)[1].max() < 0.01  # metres
    far = CURVE_3D.closest_params(points)[1] > 0.03
    np.testing.assert_array_equal(fit.inliers, ~far)
    assert fit.inlier_fraction == pytest.approx(np.mean(~far))
    assert outlier.mean() > 0.2


def test_ransac_is_deterministic_and_returns_none_below_min_fraction() -> None:
    points, _ = _noisy_branch(np.random.default_rng(4), 0.3)
    a = ransac_fit_bezier(points, 0.03, 0.5, np.random.default_rng(7))
    b = ransac_fit_bezier(points, 0.03, 0.5, np.random.default_rng(7))
    assert a is not None and b is not None
    np.testing.assert_array_equal(a.curve.control_points, b.curve.control_points)
    assert ransac_fit_bezier(points, 0.03, 0.95, np.random.default_rng(7)) is None


def test_ransac_handles_exactly_four_points() -> None:
    points = CURVE_2D(np.array([0.0, 0.3, 0.6, 1.0]))
    fit = ransac_fit_bezier(points, 1.0, 1.0, np.random.default_rng(0))
    assert fit is not None and fit.inliers.all()


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (np.zeros((3, 2)), "at least 4"),
        (np.array([[0.0, 0.0], [1.0, np.nan], [2.0, 2.0], [3.0, 3.0]]), "NaN"),
        (np.ones((6, 2)), "identical"),
        (np.zeros(8), "shape"),
    ],
)
def test_fit_rejects_bad_points(points: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        fit_bezier(points)


def test_bad_inputs_raise_value_errors() -> None:
    points = CURVE_2D(np.linspace(0.0, 1.0, 10))
    with pytest.raises(ValueError, match="shape"):
        CubicBezier(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        CubicBezier(np.full((4, 2), np.nan))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        CURVE_2D(np.array([1.5]))
    with pytest.raises(ValueError, match="4 distinct"):
        fit_bezier(points, t=np.repeat([0.0, 1.0], 5))
    with pytest.raises(ValueError, match="dimension"):
        CURVE_2D.closest_params(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="spacing"):
        CURVE_2D.resample_by_arclength(0.0)
    with pytest.raises(ValueError, match="Generator"):
        ransac_fit_bezier(points, 1.0, 0.5, rng=np.random.RandomState(0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="inlier_threshold"):
        ransac_fit_bezier(points, -1.0, 0.5, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="min_inlier_fraction"):
        ransac_fit_bezier(points, 1.0, 1.5, rng=np.random.default_rng(0))


def test_control_points_are_read_only_copies() -> None:
    source = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 1.0], [3.0, 0.0]])
    curve = CubicBezier(source)
    source[0, 0] = 99.0
    assert curve.control_points[0, 0] == 0.0
    with pytest.raises(ValueError):
        curve.control_points[0, 0] = 1.0
