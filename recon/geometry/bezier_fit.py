"""Cubic Bezier curves in 2D (pixels) and 3D (metres): least-squares fitting and RANSAC.

The curve itself (:class:`CubicBezier`: evaluation, arc length, resampling, closest points) lives
in ``recon/geometry/bezier.py``; this module fits curves to
 ordered points (:func:`fit_bezier`, :func:`ransac_fit_bezier`).

A cubic Bezier ``B(t) = sum_i b_i(t) P_i`` with Bernstein weights
``b(t) = [(1-t)^3, 3t(1-t)^2, 3t^2(1-t), t^3]`` and four control points ``P_i``. The paper models
the visible part of every branch, in the image and in space, with one such curve (section IV).
The dimension D of a curve is the width of its control points, so one class serves both uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.geometry.bezier import (
    DEFAULT_CLOSEST_SAMPLES,
    DEFAULT_NEWTON_ITERATIONS,
    DEGENERATE,
    N_CONTROL_POINTS,
    CubicBezier,
    bernstein,
    check_params,
    check_points,
    closest_params_batch,
)

__all__ = ["RansacFit", "chord_length_params", "fit_bezier", "ransac_fit_bezier"]


def _chord_params(points: np.ndarray) -> np.ndarray:
    """Chord-length parameters of validated (N, D) points; raises if all points coincide."""
    seg = np.diff(points, axis=0)
    cum = np.empty(len(points))
    cum[0] = 0.0
    np.cumsum(np.sqrt(np.einsum("ij,ij->i", seg, seg)), out=cum[1:])
    if cum[-1] <= 0.0:
        raise ValueError("points are all identical: chord-length parameters are undefined")
    return cum / cum[-1]


def chord_length_params(points: np.ndarray) -> np.ndarray:
    """(N,) cumulative chord length of ordered (N, D) points, normalised to [0, 1].

    Raises:
        ValueError: fewer than 2 points, NaN, or all points identical.
    """
    return _chord_params(check_points(points, min_count=2))


def _least_squares_control_points(points: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, D) control points minimising sum |B(t_i) - p_i|^2 (normal equations, 4x4)."""
    basis = bernstein(t)
    control_points = np.linalg.solve(basis.T @ basis, basis.T @ points)
    if not np.all(np.isfinite(control_points)):
        raise ValueError("Bezier least-squares system is singular: parameters too clustered")
    return control_points


def fit_bezier(
    points: np.ndarray, t: np.ndarray | None = None, reparametrize_iterations: int = 0
) -> CubicBezier:
    """Least-squares cubic Bezier through ordered points (end points not pinned).

    Solves the 4x4 normal equations of the Bernstein design matrix, which is well conditioned
    for parameters spread over [0, 1] (half the cost of ``np.linalg.lstsq``).

    Args:
        points: (N, D) ordered samples along the curve, N >= 4.
        t: (N,) parameters in [0, 1] with at least 4 distinct values; chord-length parameters
            when None.
        reparametrize_iterations: Times to replace ``t`` by each point's closest parameter on
            the current fit and refit (improves fits to unevenly spaced data).

    Raises:
        ValueError: fewer than 4 points (or distinct parameters), NaN, or bad ``t``.
    """
    points = check_points(points, min_count=N_CONTROL_POINTS)
    if t is None:
        t = _chord_params(points)
        distinct = np.count_nonzero(np.diff(t) > 0.0) + 1
    else:
        t = check_params(t, len(points))
        distinct = len(np.unique(t))
    if distinct < N_CONTROL_POINTS:
        raise ValueError(f"a cubic Bezier fit needs 4 distinct parameters, got {distinct}")
    if reparametrize_iterations < 0:
        raise ValueError(f"reparametrize_iterations must be >= 0, got {reparametrize_iterations}")
    curve = CubicBezier(_least_squares_control_points(points, t))
    for _ in range(reparametrize_iterations):
        t = curve.closest_params(points)[0]
        if len(np.unique(t)) < N_CONTROL_POINTS:
            break  # the points project onto too few curve parameters to refit
        curve = CubicBezier(_least_squares_control_points(points, t))
    return curve


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class RansacFit:
    """Result of :func:`ransac_fit_bezier`.

    Attributes:
        curve: The curve refit on the consensus set.
        inliers: (N,) True where the input point lies within the inlier threshold of ``curve``.
        inlier_fraction: Fraction of input points that are inliers.
    """

    curve: CubicBezier
    inliers: np.ndarray
    inlier_fraction: float


def _sample_interpolants(
    points: np.ndarray, rng: np.random.Generator, iterations: int
) -> np.ndarray:
    """(B, 4, D) control points of cubics through 4 random ordered points (B <= iterations)."""
    n = len(points)
    if n == N_CONTROL_POINTS:
        idx = np.arange(N_CONTROL_POINTS)[None]
    else:
        idx = np.sort(np.argpartition(rng.random((iterations, n)), 3, axis=1)[:, :4], axis=1)
    sample = points[idx]  # (B, 4, D)
    gaps = np.linalg.norm(np.diff(sample, axis=1), axis=2)  # (B, 3)
    total = gaps.sum(axis=1)
    # Coincident samples make the interpolation singular: drop those draws.
    ok = np.all(gaps > DEGENERATE * total[:, None], axis=1) & (total > 0.0)
    if not np.any(ok):
        return np.zeros((0, N_CONTROL_POINTS, points.shape[1]))
    sample, gaps, total = sample[ok], gaps[ok], total[ok]
    t = np.concatenate([np.zeros((len(gaps), 1)), np.cumsum(gaps, axis=1)], axis=1) / total[:, None]
    return np.linalg.solve(bernstein(t), sample)


def ransac_fit_bezier(
    points: np.ndarray,
    inlier_threshold: float,
    min_inlier_fraction: float,
    rng: np.random.Generator,
    iterations: int = 100,
    n_samples: int = DEFAULT_CLOSEST_SAMPLES,
) -> RansacFit | None:
    """Robust cubic Bezier fit to points ordered along a branch.

    Each iteration draws 4 distinct points, keeps them in input order, and interpolates them with
    chord-length parameters; all hypotheses are scored at once by counting points within
    ``inlier_threshold`` of the curve. The best consensus set is refit by least squares; the refit
    is kept unless it has fewer inliers than the hypothesis that found it.

    Args:
        points: (N, D) points ordered along the branch, N >= 4.
        inlier_threshold: Maximum point-to-curve distance of an inlier (units of ``points``;
            the paper uses 3 cm in 3D, section IV-A).
        min_inlier_fraction: Return None below this inlier fraction (paper: 0.6).
        rng: Source of the random draws.
        iterations: Number of 4-point hypotheses.
        n_samples: Dense samples per curve for the point-to-curve distances.

    Returns:
        The fit, or None when no hypothesis reaches ``min_inlier_fraction``.
    """
    points = check_points(points, min_count=N_CONTROL_POINTS)
    if not (math.isfinite(inlier_threshold) and inlier_threshold > 0.0):
        raise ValueError(f"inlier_threshold must be positive, got {inlier_threshold}")
    if not 0.0 <= min_inlier_fraction <= 1.0:
        raise ValueError(f"min_inlier_fraction must be in [0, 1], got {min_inlier_fraction}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")

    hypotheses = _sample_interpolants(points, rng, iterations)
    if len(hypotheses) == 0:
        return None
    dist = closest_params_batch(hypotheses, points, n_samples, DEFAULT_NEWTON_ITERATIONS)[1]
    counts = np.count_nonzero(dist <= inlier_threshold, axis=1)
    best = int(np.argmax(counts))
    curve = CubicBezier(hypotheses[best])
    inliers = dist[best] <= inlier_threshold
    if inliers.sum() >= N_CONTROL_POINTS:
        try:
            refit = fit_bezier(points[inliers])
        except ValueError:  # consensus points all identical
            refit = None
        if refit is not None:
            refit_inliers = refit.closest_params(points, n_samples)[1] <= inlier_threshold
            if refit_inliers.sum() >= inliers.sum():
                curve, inliers = refit, refit_inliers
    fraction = float(inliers.mean())
    if fraction < min_inlier_fraction:
        return None
    return RansacFit(curve=curve, inliers=inliers, inlier_fraction=fraction)
