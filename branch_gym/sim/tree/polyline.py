"""Polyline and cubic-Bezier helpers of the tree generator (``generator.py``)."""

from __future__ import annotations

import math

import numpy as np

# Bezier samples before resampling by arc length (~1 mm chords: sagitta far below 1 um).
_BEZIER_EVAL_SAMPLES = 1024


def axis_frame(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose columns are x, y, z axes with z = ``axis`` (unit, not along x)."""
    y_axis = np.cross(axis, [1.0, 0.0, 0.0])
    y_axis /= np.linalg.norm(y_axis)
    return np.stack([np.cross(y_axis, axis), y_axis, axis], axis=1)


def eval_cubic_bezier(control: np.ndarray) -> np.ndarray:
    """(S, 3) points of the cubic Bezier with (4, 3) ``control`` points, uniform in parameter."""
    t = np.linspace(0.0, 1.0, _BEZIER_EVAL_SAMPLES)[:, None]
    u = 1.0 - t
    return (
        u**3 * control[0]
        + 3 * u**2 * t * control[1]
        + 3 * u * t**2 * control[2]
        + t**3 * control[3]
    )


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """(N,) arc length in metres from the first of the (N, 3) ``points`` to each point."""
    steps = np.diff(points, axis=0)
    return np.concatenate([[0.0], np.cumsum(np.sqrt(np.einsum("ij,ij->i", steps, steps)))])


def resample_polyline(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Resample (N, 3) ``points`` evenly by arc length, at most ``spacing_m`` apart, same ends."""
    arc_m = arc_lengths(points)
    n_out = max(math.ceil(arc_m[-1] / spacing_m) + 1, 2)
    targets = np.linspace(0.0, arc_m[-1], n_out)
    return np.stack([np.interp(targets, arc_m, points[:, k]) for k in range(3)], axis=1)


def segment_at_height(points: np.ndarray, height_m: float) -> tuple[int, float]:
    """Segment index i and fraction in [0, 1] where the (N, 3) polyline first reaches height_m."""
    rising_z = np.maximum.accumulate(points[:, 2])
    index = int(np.clip(np.searchsorted(rising_z, height_m) - 1, 0, len(points) - 2))
    z0, z1 = points[index, 2], points[index + 1, 2]
    frac = 0.0 if z1 == z0 else float(np.clip((height_m - z0) / (z1 - z0), 0.0, 1.0))
    return index, frac
