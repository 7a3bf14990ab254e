"""2D curve fitting: primary and secondary branch curves from a branch mask (paper section IV-B).

1. Clean the mask and build its skeleton graph (:mod:`recon.curve2d.skeleton`), small gaps
   between skeleton components bridged (:mod:`recon.curve2d.skeleton_bridge`).
2. Orient every edge along the image motion direction (up, -v, by default), giving a DAG.
3. Primary: search the DAG's directed paths from its sources (every prefix counts), largest
   connected components first; fit a cubic Bezier to each path's pixels by least squares; its
   inliers are skeleton pixels within 4 px of the curve, and its score is the number of distinct
   inlier rows (the paper; generally: distinct pixel positions along the motion direction), or
   the inliers' extent along the motion direction (the authors' code). The best score wins.
   Paths are tried widest first and skipped when they cannot win: before fitting when the
   rows covered by their own pixels (widened by two thresholds) cannot beat the best, after
   fitting when the rows spanned by the control points (a Bezier lies in their convex hull,
   widened by one threshold) cannot. The search is exponential in skeleton loops and stops
   after ``max_primary_paths``.
4. Secondaries: for each edge leaving an interior node of the primary path (undirected graph,
   primary edges removed), search the simple paths starting with that edge; the best-fitting
   one (most of its own pixels within 4 px of its curve, among those with a high enough inlier
   rate) is kept when its curve is at least 20 px long; its free tip is extended along its end
   tangent to the silhouette's end (thinning stops about a radius short).
5. Sample the primary every 30 px of arc length, each secondary every 10 px (at least 7
   samples), with the radius of the nearest pixel of its own skeleton path; radii beyond the
   quartile fence are replaced by the median. Samples on a bridged gap are flagged
   (``Curve2D.bridged``) and not lifted.

Pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.

Where the steps live: result types and config in ``recon/curve2d/types.py``,
graph paths in ``recon/curve2d/path_search.py``, step 3 in ``recon/curve2d/primary.py``, step 4 in
``recon/curve2d/secondary.py``; this module runs them (:func:`fit_mask_curves`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from recon.curve2d.path_search import SearchGraph
from recon.curve2d.primary import PrimaryPrior, find_primary
from recon.curve2d.secondary import find_secondaries
from recon.curve2d.skeleton import extract_skeleton, preprocess_mask
from recon.curve2d.skeleton_graph import SkeletonGraph
from recon.curve2d.types import (
    NEWTON_ITERATIONS,
    Curve2D,
    Curve2DConfig,
    MaskCurves,
    make_curve2d,
)

__all__ = ["fit_mask_curves", "points_in_mask"]

logger = logging.getLogger(__name__)

# A sample this close to a bridge pixel and off the mask lies on a bridged gap (a curve passes
# within a pixel or so of the straight bridge line it was fitted to).
BRIDGE_SAMPLE_PX = 2.5


def fit_mask_curves(
    mask: np.ndarray,
    config: Curve2DConfig = Curve2DConfig(),  # noqa: B008  (frozen: safe to share)
    motion_direction_uv: np.ndarray | None = None,
    prior: PrimaryPrior | None = None,
) -> MaskCurves:
    """Fit the primary and secondary branch curves of a binary mask.

    Args:
        mask: (H, W) branch mask, bool or {0, 1}.
        config: Fitting parameters (paper defaults).
        motion_direction_uv: Image direction (u, v) of the scan, overriding
            ``config.motion_direction_uv`` (e.g. for a rotated camera).
        prior: The 3D model's primary projected into this frame; when given, a primary that
            agrees with it is preferred over a higher-scoring one that does not.

    Returns:
        The curves; ``primary`` is None for empty, tiny, speckled or blob-like masks.

    Raises:
        ValueError: the mask is not 2-D binary, or the motion direction is zero or not finite.
    """
    direction = np.asarray(
        config.motion_direction_uv if motion_direction_uv is None else motion_direction_uv,
        dtype=float,
    )
    norm = np.linalg.norm(direction) if direction.shape == (2,) else 0.0
    if not (np.isfinite(norm) and norm > 0.0):
        raise ValueError(f"motion_direction_uv must be a non-zero finite 2-vector, got {direction}")
    direction = direction / norm
    clean = preprocess_mask(mask, config.skeleton)
    graph = extract_skeleton(clean, config.skeleton)
    sg = SearchGraph(graph)
    path, primary, evaluated, truncated = _primary(sg, direction, config, prior, clean.shape)
    if primary is None and prior is not None and math.isfinite(prior.max_turn_deg):
        # The path that agrees with the model is no primary (the model's stub below an occluder
        # that cuts the trunk): take the best path that does not turn off the model. The modeler
        # finds it inconsistent and restarts on it, where no primary at all lost the branch.
        # Every path "agrees" with that prior, so it vouches for none (the blob test holds).
        anywhere = replace(prior, min_fraction=0.0, vouches=False)
        path, primary, more, cut = _primary(sg, direction, config, anywhere, clean.shape)
        evaluated, truncated = evaluated + more, truncated or cut
    if truncated:
        logger.debug("primary path search truncated after %d paths", evaluated)
    if path is None or primary is None:
        return MaskCurves(None, [], truncated, evaluated, graph, clean)
    secondaries, more, cut = find_secondaries(sg, path, primary, config, clean)
    if len(graph.bridge_uv):
        primary = _flag_bridged(primary, graph, clean)
        secondaries = [_flag_bridged(s, graph, clean) for s in secondaries]
    return MaskCurves(primary, secondaries, truncated or cut, evaluated + more, graph, clean)


def _primary(
    sg: SearchGraph,
    direction: np.ndarray,
    config: Curve2DConfig,
    prior: PrimaryPrior | None,
    shape: tuple[int, ...],
) -> tuple[tuple[int, ...] | None, Curve2D | None, int, bool]:
    """:func:`find_primary`'s path as a :class:`Curve2D`: (path, primary or None when it is too
    short or not branch-like, paths evaluated, truncated)."""
    path, curve, score, evaluated, truncated = find_primary(sg, direction, config, prior)
    if path is None or curve is None:
        return None, None, evaluated, truncated
    pixels, radii = sg.path_pixels(path)
    if (curve.control_points[-1] - curve.control_points[0]) @ direction < 0.0:
        # Keep B(0) at the start of the scan direction (a path hooked at its end can flip it).
        curve, pixels, radii = curve.reversed(), pixels[::-1], radii[::-1]
    dist = curve.closest_params(pixels, newton_iterations=NEWTON_ITERATIONS)[1]
    fraction = float(np.mean(dist <= config.inlier_threshold_px))
    primary = make_curve2d(curve, pixels, radii, score, fraction, config)
    if primary.length_px < config.min_primary_length_px:
        return path, None, evaluated, truncated
    if not _branch_like(primary, pixels, direction, shape, config) and not (
        prior is not None and prior.vouches and prior.agrees(curve)  # the model vouches for it
    ):
        return path, None, evaluated, truncated
    return path, primary, evaluated, truncated


def _branch_like(
    primary: Curve2D,
    pixels: np.ndarray,
    direction: np.ndarray,
    shape: tuple[int, ...],
    config: Curve2DConfig,
) -> bool:
    """Whether a primary candidate is elongated like a branch, not a blob or a full mask: at
    least ``min_primary_elongation`` diameters long, or spanning the view along the scan
    direction (``primary_view_span``) while at most ``max_spanning_width`` of it wide and
    smooth (``spanning_min_inlier_fraction``).

    Args:
        primary: The candidate curve.
        pixels: (P, 2) its skeleton path's pixels (u, v).
        direction: (2,) unit scan direction (u, v).
        shape: (H, W) of the mask.
        config: The thresholds.
    """
    diameter_px = 2.0 * float(primary.radii_px.mean())
    if primary.length_px >= config.min_primary_elongation * diameter_px:
        return True
    border = config.skeleton.border_px
    interior = np.array([shape[1] - 1 - 2 * border, shape[0] - 1 - 2 * border], dtype=float)
    along = float(np.abs(direction) @ interior)
    across = float(np.abs(direction[::-1]) @ interior)
    progress = pixels @ direction
    span = float(progress.max() - progress.min())
    # The median radius: the border band's cut narrows a wide mask's skeleton radii at its ends.
    return (
        span >= config.primary_view_span * along
        and 2.0 * float(np.median(primary.radii_px)) <= config.max_spanning_width * across
        and primary.inlier_fraction >= config.spanning_min_inlier_fraction
    )


def _flag_bridged(curve: Curve2D, graph: SkeletonGraph, mask: np.ndarray) -> Curve2D:
    """Flag the samples that lie off the mask next to a bridge of the skeleton."""
    near = cKDTree(graph.bridge_uv).query(curve.samples_px)[0] <= BRIDGE_SAMPLE_PX
    return replace(curve, bridged=near & ~points_in_mask(mask, curve.samples_px))


def points_in_mask(mask: np.ndarray, points_uv: np.ndarray) -> np.ndarray:
    """(N,) True where the (N, 2) points (u, v), rounded to pixels, fall on mask pixels."""
    points_uv = np.asarray(points_uv, dtype=float).reshape(-1, 2)
    inside = np.all(np.isfinite(points_uv), axis=1)
    uv = np.zeros((len(points_uv), 2), dtype=int)
    uv[inside] = np.rint(points_uv[inside]).astype(int)
    h, w = mask.shape
    inside &= (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    result = np.zeros(len(points_uv), dtype=bool)
    result[inside] = mask[uv[inside, 1], uv[inside, 0]]
    return result
