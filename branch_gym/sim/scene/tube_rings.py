"""Where a swept tube's rings go along a branch centerline, and how they are oriented.

The polyline is checked and resampled densely, rings are kept where the centerline bends or the
radius changes (Ramer-Douglas-Peucker within the chord and radius tolerances, split on long
straight stretches), and each ring gets a tangent and a rotation-minimising normal (no twist:
:func:`recon.geometry.frames.rotation_minimising_frames`, the one implementation, which the PLY
meshes of reconstructed models use too).
``branch_gym/sim/scene/tree_mesh.py`` builds the triangle mesh on these rings.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np

from recon.geometry.frames import rotation_minimising_frames

if TYPE_CHECKING:
    from branch_gym.sim.scene.tree_mesh import TubeMeshConfig

_DENSE_STEP_M = 0.001  # working resolution of the centerline (the ground truth is 1 mm dense)
_MIN_SEGMENT_M = 1e-9  # shorter steps are duplicate points

__all__ = [
    "check_polyline",
    "densify",
    "ring_tangents",
    "rotation_minimising_frames",
    "select_rings",
]


def check_polyline(points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points, dtype=float)
    radii = np.asarray(radii, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise ValueError(f"points must have shape (N>=2, 3), got {points.shape}")
    if radii.shape != (len(points),):
        raise ValueError(f"radii must have shape ({len(points)},), got {radii.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(radii))):
        raise ValueError("points and radii must be finite")
    if np.any(radii <= 0):
        raise ValueError(f"radii must be positive, got min {radii.min()}")
    return points, radii


def densify(points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample to equal steps of at most ``_DENSE_STEP_M``: points, radii and arc length (m)."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], steps > _MIN_SEGMENT_M])
    if keep.sum() < 2:
        raise ValueError("the polyline has zero length")
    points, radii = points[keep], radii[keep]
    arc = np.concatenate([[0.0], np.cumsum(steps[keep[1:]])])
    grid = np.linspace(0.0, arc[-1], max(2, math.ceil(arc[-1] / _DENSE_STEP_M) + 1))
    dense = np.stack([np.interp(grid, arc, points[:, k]) for k in range(3)], axis=1)
    return dense, np.interp(grid, arc, radii), grid


def select_rings(
    points: np.ndarray, radii: np.ndarray, arc: np.ndarray, config: TubeMeshConfig
) -> np.ndarray:
    """Sorted indices of the dense points that become rings.

    Ramer-Douglas-Peucker on (x, y, z, scaled r) keeps the centerline within
    ``max_chord_error_m`` of the dense one and the radius within ``max_radius_error_m``; then
    stretches longer than ``max_ring_spacing_m`` are split evenly.
    """
    radius_weight = config.max_chord_error_m / config.max_radius_error_m
    augmented = np.hstack([points, radius_weight * radii[:, None]])
    keep = {0, len(points) - 1}
    stack = [(0, len(points) - 1)]
    while stack:
        first, last = stack.pop()
        if last - first < 2:
            continue
        worst, distance = _farthest_from_chord(augmented, first, last)
        if distance > config.max_chord_error_m:
            keep.add(worst)
            stack += [(first, worst), (worst, last)]
    rings = sorted(keep)
    split = [rings[0]]
    for first, last in itertools.pairwise(rings):
        pieces = max(1, math.ceil((arc[last] - arc[first]) / config.max_ring_spacing_m - 1e-9))
        split += np.linspace(first, last, pieces + 1)[1:].round().astype(int).tolist()
    return np.unique(split)


def _farthest_from_chord(points: np.ndarray, first: int, last: int) -> tuple[int, float]:
    """Index and distance of the point of ``points[first:last+1]`` farthest from that chord."""
    chord = points[last] - points[first]
    offsets = points[first : last + 1] - points[first]
    along = np.clip(offsets @ chord / max(float(chord @ chord), _MIN_SEGMENT_M**2), 0.0, 1.0)
    distances = np.linalg.norm(offsets - along[:, None] * chord, axis=1)
    worst = int(np.argmax(distances))
    return first + worst, float(distances[worst])


def ring_tangents(centres: np.ndarray) -> np.ndarray:
    """(R, 3) unit tangents: bisectors of the adjacent segments, segment direction at the ends."""
    segments = np.diff(centres, axis=0)
    segments /= np.linalg.norm(segments, axis=1, keepdims=True)
    tangents = np.empty_like(centres)
    tangents[0], tangents[-1] = segments[0], segments[-1]
    tangents[1:-1] = segments[:-1] + segments[1:]
    return tangents / np.linalg.norm(tangents, axis=1, keepdims=True)
