"""The cubic Bezier curve in 2D (pixels) and 3D (metres): evaluation, derivatives, arc length,
resampling and closest points (:class:`CubicBezier`), with the Bernstein basis and input checks
that the fitting in ``recon/geometry/bezier_fit.py`` shares.

A cubic Bezier ``B(t) = sum_i b_i(t) P_i`` with Bernstein weights
``b(t) = [(1-t)^3, 3t(1-t)^2, 3t^2(1-t), t^3]`` and four control points ``P_i``. The paper models
the visible part of every branch, in the image and in space, with one such curve (section IV).
The dimension D of a curve is the width of its control points, so one class serves both uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

# Dense samples seeding the closest-point search; Newton steps then refine each parameter.
DEFAULT_CLOSEST_SAMPLES = 48
DEFAULT_NEWTON_ITERATIONS = 2
# Dense polyline used as the arc-length table: relative length error ~1e-5 for branch-like curves.
ARCLENGTH_TABLE_SAMPLES = 257
# Relative tolerance for degenerate geometry: tangents shorter than this fraction of the longest
# have no direction (cusps); sample gaps below it make an interpolation singular.
DEGENERATE = 1e-9
N_CONTROL_POINTS = 4
# Bernstein -> power basis: rows give a, b, c, d of B(t) = a t^3 + b t^2 + c t + d.
_POWER_BASIS = np.array(
    [[-1.0, 3.0, -3.0, 1.0], [3.0, -6.0, 3.0, 0.0], [-3.0, 3.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]
)


def bernstein(t: np.ndarray) -> np.ndarray:
    """(..., 4) cubic Bernstein weights at parameters ``t`` of shape (...)."""
    mt = 1.0 - t
    out = np.empty((*np.shape(t), N_CONTROL_POINTS))
    out[..., 0] = mt * mt * mt
    out[..., 1] = 3.0 * t * mt * mt
    out[..., 2] = 3.0 * t * t * mt
    out[..., 3] = t * t * t
    return out


def check_points(points: np.ndarray, name: str = "points", min_count: int = 1) -> np.ndarray:
    """Validate an (N, D) finite float array with at least ``min_count`` rows."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] < 1:
        raise ValueError(f"{name} must have shape (N, D), got {points.shape}")
    if len(points) < min_count:
        raise ValueError(f"{name} needs at least {min_count} points, got {len(points)}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return points


def check_params(t: np.ndarray, count: int | None = None) -> np.ndarray:
    """Validate curve parameters: finite, within [0, 1], optionally exactly ``count`` of them."""
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"curve parameters t must have shape (N,), got {t.shape}")
    if count is not None and len(t) != count:
        raise ValueError(f"curve parameters t must have {count} entries, got {len(t)}")
    if not np.all(np.isfinite(t)):
        raise ValueError("curve parameters t contain NaN or infinite values")
    if np.any(t < 0.0) or np.any(t > 1.0):
        raise ValueError("curve parameters t must lie in [0, 1]")
    return t


def closest_params_batch(
    control_points: np.ndarray, points: np.ndarray, n_samples: int, newton_iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Closest curve parameters for B curves at once.

    Args:
        control_points: (B, 4, D) control points of B curves.
        points: (N, D) query points.
        n_samples: Dense samples per curve seeding the search.
        newton_iterations: Newton refinements of each seed.

    Returns:
        t: (B, N) parameters in [0, 1]; dist: (B, N) point-to-curve distances.
    """
    samples = _seed_basis(n_samples) @ control_points  # (B, S, D)
    # argmin over samples of |s|^2 - 2 s.p equals that of |s - p|^2; samples on the middle axis
    # keep the reduction vectorised over the points.
    partial = (samples * samples).sum(axis=2)[:, :, None] - 2.0 * (samples @ points.T)
    nearest = np.argmin(partial, axis=1)  # (B, N)
    seed_t = nearest / (n_samples - 1.0)
    seed_sq = np.take_along_axis(partial, nearest[:, None, :], axis=1)[:, 0, :] + np.einsum(
        "nd,nd->n", points, points
    )
    if newton_iterations == 0:
        return seed_t, np.sqrt(np.maximum(seed_sq, 0.0))
    # Coordinates first, so every array op runs over the long (B, N) axes. The power basis
    # B(t) = ((a t + b) t + c) t + d makes B, B' and B'' cheap to evaluate.
    a, b, c, d = (_POWER_BASIS @ control_points).transpose(1, 2, 0)[..., None]  # (D, B, 1)
    d = d - points.T[:, None, :]  # (D, B, N): B(t) - p = ((a t + b) t + c) t + d
    a3, b2, a6 = 3.0 * a, 2.0 * b, 6.0 * a
    t = seed_t
    for _ in range(newton_iterations):
        diff = ((a * t + b) * t + c) * t + d
        vel = (a3 * t + b2) * t + c
        grad = (diff * vel).sum(axis=0)
        speed2 = (vel * vel).sum(axis=0)
        hess = speed2 + (diff * (a6 * t + b2)).sum(axis=0)
        # Newton where the squared distance is locally convex, Gauss-Newton elsewhere.
        denom = np.where(hess > 0.0, hess, speed2)
        step = np.divide(grad, denom, out=np.zeros_like(grad), where=denom > 0.0)
        t = np.clip(t - step, 0.0, 1.0)
    diff = ((a * t + b) * t + c) * t + d
    sq = (diff * diff).sum(axis=0)
    worse = seed_sq < sq  # keep the seed where a step overshot a sharp bend
    return np.where(worse, seed_t, t), np.sqrt(np.maximum(np.where(worse, seed_sq, sq), 0.0))


@lru_cache(maxsize=8)
def _seed_basis(n_samples: int) -> np.ndarray:
    """(S, 4) Bernstein weights at ``n_samples`` equally spaced parameters (cached, read-only)."""
    basis = bernstein(np.linspace(0.0, 1.0, n_samples))
    basis.setflags(write=False)
    return basis


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class CubicBezier:
    """A cubic Bezier curve in D dimensions.

    Attributes:
        control_points: (4, D) control points, P0 = B(0) and P3 = B(1); same units as the data
            (pixels for image curves, metres for world curves). Stored as a read-only float copy.
    """

    control_points: np.ndarray

    def __post_init__(self) -> None:
        cp = np.array(self.control_points, dtype=float)
        if cp.ndim != 2 or cp.shape[0] != N_CONTROL_POINTS or cp.shape[1] < 1:
            raise ValueError(f"control_points must have shape (4, D), got {cp.shape}")
        if not np.all(np.isfinite(cp)):
            raise ValueError("control_points contain NaN or infinite values")
        cp.setflags(write=False)
        object.__setattr__(self, "control_points", cp)

    @property
    def dim(self) -> int:
        """Dimension D of the curve's space."""
        return int(self.control_points.shape[1])

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """(N, D) curve points at (N,) parameters in [0, 1]."""
        return bernstein(check_params(t)) @ self.control_points

    def tangent(self, t: np.ndarray) -> np.ndarray:
        """(N, D) first derivative dB/dt at (N,) parameters (units per unit parameter)."""
        t = check_params(t)
        mt = 1.0 - t
        weights = np.stack([mt * mt, 2.0 * t * mt, t * t], axis=-1)
        return weights @ (3.0 * np.diff(self.control_points, axis=0))

    def second_derivative(self, t: np.ndarray) -> np.ndarray:
        """(N, D) second derivative d2B/dt2 at (N,) parameters."""
        t = check_params(t)
        weights = np.stack([1.0 - t, t], axis=-1)
        return weights @ (6.0 * np.diff(self.control_points, n=2, axis=0))

    @cached_property
    def _arclength_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Dense parameters (S,) and cumulative polyline length (S,) from B(0), computed once."""
        t = np.linspace(0.0, 1.0, ARCLENGTH_TABLE_SAMPLES)
        pts = bernstein(t) @ self.control_points
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        return t, np.concatenate([[0.0], np.cumsum(seg)])

    def length(self, n_samples: int = ARCLENGTH_TABLE_SAMPLES) -> float:
        """Arc length, as the length of the polyline through ``n_samples`` equally spaced params."""
        if n_samples == ARCLENGTH_TABLE_SAMPLES:
            return float(self._arclength_table[1][-1])
        if n_samples < 2:
            raise ValueError(f"n_samples must be >= 2, got {n_samples}")
        pts = bernstein(np.linspace(0.0, 1.0, n_samples)) @ self.control_points
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    def resample_by_count(self, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        """``n_points`` points equally spaced in arc length, from B(0) to B(1) inclusive.

        Returns:
            points: (n_points, D) curve points; t: (n_points,) their parameters.
        """
        if n_points < 2:
            raise ValueError(f"n_points must be >= 2, got {n_points}")
        t_table, s_table = self._arclength_table
        targets = np.linspace(0.0, s_table[-1], n_points)
        t = np.interp(targets, s_table, t_table)
        t[0], t[-1] = 0.0, 1.0
        return bernstein(t) @ self.control_points, t

    def resample_by_arclength(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Points at equal arc-length spacing no larger than ``spacing``, both ends included.

        The curve is cut into ``ceil(length / spacing)`` equal pieces (at least one), so the actual
        spacing is ``length / pieces <= spacing`` and uniform along the curve.

        Returns:
            points: (K, D) curve points; t: (K,) their parameters, K >= 2.
        """
        if not (math.isfinite(spacing) and spacing > 0.0):
            raise ValueError(f"spacing must be positive and finite, got {spacing}")
        pieces = max(1, math.ceil(self.length() / spacing))
        return self.resample_by_count(pieces + 1)

    def closest_params(
        self,
        points: np.ndarray,
        n_samples: int = DEFAULT_CLOSEST_SAMPLES,
        newton_iterations: int = DEFAULT_NEWTON_ITERATIONS,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Closest curve point of each query point (t clipped to [0, 1], so ends count).

        The nearest of ``n_samples`` dense samples seeds ``newton_iterations`` Newton steps on
        ``(B(t) - p) . B'(t) = 0``; a refinement that does not reduce the distance is discarded.

        Args:
            points: (N, D) query points, same units and dimension as the curve.

        Returns:
            t: (N,) parameters in [0, 1]; dist: (N,) point-to-curve distances.
        """
        points = check_points(points, min_count=0)
        if points.shape[1] != self.dim:
            raise ValueError(f"points must have dimension {self.dim}, got {points.shape[1]}")
        if n_samples < 2 or newton_iterations < 0:
            raise ValueError(
                f"need n_samples >= 2 and newton_iterations >= 0, got {n_samples} and "
                f"{newton_iterations}"
            )
        if len(points) == 0:
            return np.zeros(0), np.zeros(0)
        t, dist = closest_params_batch(
            self.control_points[None], points, n_samples, newton_iterations
        )
        return t[0], dist[0]

    def max_bend_angle_deg(self, n_samples: int = 64) -> float:
        """Largest angle in degrees between any two tangent directions along the curve.

        Tangents are sampled at ``n_samples`` equally spaced parameters; a straight curve gives 0,
        a half circle 180. This is the pairwise maximum, not the accumulated turning, so an S bend
        reports its widest tangent spread.
        """
        tangents = self.tangent(np.linspace(0.0, 1.0, n_samples))
        norms = np.linalg.norm(tangents, axis=1)
        if norms.max() <= 0.0:
            return 0.0
        unit = tangents[norms > DEGENERATE * norms.max()]
        unit = unit / np.linalg.norm(unit, axis=1, keepdims=True)
        min_cos = float(np.clip((unit @ unit.T).min(), -1.0, 1.0))
        return math.degrees(math.acos(min_cos))

    def reversed(self) -> CubicBezier:
        """The same curve traversed from B(1) to B(0)."""
        return CubicBezier(self.control_points[::-1])
