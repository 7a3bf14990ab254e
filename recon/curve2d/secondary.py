"""Secondary curve candidates of the 2D curve fitting (``recon/curve2d/fit.py``, step 4).

:func:`find_secondaries` searches the simple paths leaving each interior node of the primary path
(undirected graph, primary edges removed), keeps the best-fitting candidate per starting edge and
flags its samples that lie inside the primary's silhouette.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from recon.curve2d.path_search import SearchGraph, enumerate_paths, undirected_adjacency
from recon.curve2d.types import (
    MIN_FIT_PIXELS,
    NEWTON_ITERATIONS,
    Curve2D,
    Curve2DConfig,
    make_curve2d,
)
from recon.geometry.bezier_fit import fit_bezier


def find_secondaries(
    sg: SearchGraph,
    primary_path: tuple[int, ...],
    primary: Curve2D,
    config: Curve2DConfig,
    mask: np.ndarray | None = None,
) -> tuple[list[Curve2D], int, bool]:
    """Secondary curves off the primary path: (curves, paths evaluated, truncated).

    Args:
        sg: The skeleton graph.
        primary_path: The primary's half-edge path.
        primary: The primary curve.
        config: Fitting parameters.
        mask: (H, W) bool clean mask; when given, each candidate's skeleton path is extended at
            its free tip to the silhouette's end (``config.extend_secondary_tips``).
    """
    nodes = sg.path_nodes(primary_path)
    primary_nodes = set(nodes)
    adjacency = undirected_adjacency(sg, {h // 2 for h in primary_path})
    budget, evaluated, truncated = config.max_secondary_paths, 0, False
    found: list[Curve2D] = []
    for junction in nodes[1:-1]:
        for half_edge, other in adjacency[junction]:
            if other in primary_nodes or budget == 0:
                truncated |= budget == 0
                continue
            paths, cut = enumerate_paths(adjacency, [(half_edge,)], sg, primary_nodes, budget)
            budget -= len(paths)
            evaluated += len(paths)
            truncated |= cut
            best = _best_secondary(sg, paths, config, mask)
            if best is not None:
                found.append(best)
    return _flag_inside_primary(found, primary), evaluated, truncated


def _best_secondary(
    sg: SearchGraph,
    paths: list[tuple[int, ...]],
    config: Curve2DConfig,
    mask: np.ndarray | None = None,
) -> Curve2D | None:
    """The path with most own-pixel inliers among those with a high inlier rate and a limited
    bend, if its curve is long enough (its tip extended to the silhouette's end in ``mask``)."""
    best, best_score = None, 0.0
    for path in paths:
        pixels, radii = sg.path_pixels(path)
        if len(pixels) < MIN_FIT_PIXELS or len(pixels) <= best_score:
            continue  # too short to fit, or to beat the best: its inliers are its pixels at most
        curve = fit_bezier(pixels)
        dist = curve.closest_params(pixels, newton_iterations=NEWTON_ITERATIONS)[1]
        inliers = dist <= config.inlier_threshold_px
        score, fraction = float(inliers.sum()), float(inliers.mean())
        if (
            score > best_score
            and fraction >= config.min_secondary_inlier_fraction
            and curve.max_bend_angle_deg() <= config.max_secondary_bend_deg
        ):
            best, best_score = (curve, pixels, radii, score, fraction), score
    if best is None or best[0].length() < config.min_secondary_length_px:
        return None
    curve, pixels, radii, score, fraction = best
    if mask is not None and config.extend_secondary_tips:
        tip = _tip_extension(pixels, radii, mask, config)
        if len(tip):
            pixels = np.vstack([pixels, tip])
            radii = np.concatenate([radii, np.full(len(tip), radii[-1])])
            curve = fit_bezier(pixels)
    return make_curve2d(
        curve,
        pixels,
        radii,
        score,
        fraction,
        config,
        spacing_px=config.secondary_sample_spacing_px,
        min_samples=config.secondary_min_samples,
    )


def _tip_extension(
    pixels: np.ndarray, radii: np.ndarray, mask: np.ndarray, config: Curve2DConfig
) -> np.ndarray:
    """Points from a skeleton path's last pixel along its end tangent to the silhouette's end.

    Thinning stops about one radius short of a branch's free end; seen receding at an angle a
    from the viewing ray that radius is r / sin(a) of the branch's length (measured: 1.7 cm of
    a 12 cm branch at 15 deg). A tip cut by the image border stays: the mask ends there.
    """
    end = pixels[-1].astype(float)
    steps = np.linalg.norm(np.diff(pixels, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    back = pixels[int(np.searchsorted(arc, arc[-1] - config.tip_tangent_px))]
    direction = end - back
    norm = float(np.linalg.norm(direction))
    if norm == 0.0:
        return np.zeros((0, 2))
    direction /= norm
    reach = config.tip_extension_radii * float(radii[-1]) + 1.0
    along = np.arange(1.0, reach, 1.0)
    points = end + along[:, None] * direction
    uv = np.rint(points).astype(int)
    h, w = mask.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    on = np.zeros(len(points), dtype=bool)
    on[inside] = mask[uv[inside, 1], uv[inside, 0]]
    off = np.flatnonzero(~on)
    n = int(off[0]) if len(off) else len(points)
    # Stop half a radius inside the silhouette's end: the end's own centre, not its outline.
    n = max(0, n - int(np.ceil(0.5 * float(radii[-1]))))
    return points[:n]


def _flag_inside_primary(secondaries: list[Curve2D], primary: Curve2D) -> list[Curve2D]:
    """Mark secondary samples closer to the primary curve than the primary's radius there."""
    if not secondaries:
        return []
    samples = np.concatenate([s.samples_px for s in secondaries])
    t, dist = primary.curve.closest_params(samples)
    inside = dist < np.interp(t, primary.sample_t, primary.radii_px)
    splits = np.cumsum([len(s.samples_px) for s in secondaries])[:-1]
    flags = np.split(inside, splits)
    return [replace(s, inside_primary=f) for s, f in zip(secondaries, flags, strict=True)]
