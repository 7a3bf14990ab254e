"""2D curve fitting: primary and secondary branch curves from a branch mask (paper section IV-B).

1. Clean the mask and build its skeleton graph (:mod:`recon.skeleton`).
2. Orient every edge along the image motion direction (up, -v, by default), giving a DAG.
3. Primary: search the DAG's directed paths from its sources (every prefix counts); fit a
   cubic Bezier to each path's pixels by least
   squares; its inliers are skeleton pixels within 4 px of the curve, and its score is the number
   of distinct inlier rows (the paper; generally: distinct pixel positions along the motion
   direction), or the inliers' extent along the motion direction (the authors' code). The best
   score wins. A path's score cannot exceed what its control points' span allows (a Bezier lies in
   its control points' convex hull), so paths that cannot beat the best so far skip the inlier
   count. The search is exponential in skeleton loops and stops after ``max_primary_paths``.
4. Secondaries: for each edge leaving an interior node of the primary path (undirected graph,
   primary edges removed), search the simple paths starting with that edge; the best-fitting
   one (most of its own pixels within 4 px of its curve, among those with a high enough inlier
   rate) is kept when its curve is at least 20 px long.
5. Sample each curve every 30 px of arc length with the radius of the nearest pixel of its own
   skeleton path; radii beyond the quartile fence are replaced by the median.

Pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from recon.bezier import CubicBezier, fit_bezier
from recon.skeleton import SkeletonConfig, SkeletonGraph, extract_skeleton, preprocess_mask

logger = logging.getLogger(__name__)

_MIN_FIT_PIXELS = 4  # a cubic Bezier has 4 control points
_QUARTILES = np.array([0.25, 0.5, 0.75])


@dataclass(frozen=True)
class Curve2DConfig:
    """Parameters of the 2D curve fitting.

    Attributes:
        skeleton: Mask cleaning and skeleton options.
        motion_direction_uv: Image direction (u, v) the camera scans along; edges are oriented
            along it and primary samples run along it (paper IV-B: up, -Y).
        inlier_threshold_px: Skeleton pixels this close to a curve are its inliers (paper IV-B).
        score: ``"unique_rows"`` (paper IV-B: distinct inlier rows) or ``"projected_extent"``
            (authors' code: inlier length along the motion direction).
        sample_spacing_px: Arc-length spacing of the curve samples (paper IV-A: 30 px).
        min_samples: Fewest samples per curve; short curves are sampled more densely (ours: a
            3D curve needs a start, a middle and an end).
        radius_fence_iqr: Radii beyond this many interquartile ranges outside the quartiles are
            replaced by the median (reference.md: the quartile fence, 1.5).
        min_primary_length_px: Shorter best primary curves are rejected (ours: speckle noise
            yields short, well-fitting fragments; the paper's primary spans the view).
        min_primary_elongation: Reject a primary whose length is below this many mean diameters
            (ours: a full or blob-like mask is not a branch).
        min_secondary_length_px: Shortest secondary curve (reference.md: 20 px).
        min_secondary_inlier_fraction: Fewest of a secondary path's pixels within the inlier
            threshold of its curve (ours; the paper asks for an inlier rate "high enough").
        max_primary_paths: Cap on DAG paths examined for the primary (ours: bounds the search
            that is exponential in skeleton loops).
        max_secondary_paths: Cap on paths examined for all secondaries together (ours).
    """

    skeleton: SkeletonConfig = field(default_factory=SkeletonConfig)
    motion_direction_uv: tuple[float, float] = (0.0, -1.0)
    inlier_threshold_px: float = 4.0
    score: Literal["unique_rows", "projected_extent"] = "unique_rows"
    sample_spacing_px: float = 30.0
    min_samples: int = 3
    radius_fence_iqr: float = 1.5
    min_primary_length_px: float = 40.0
    min_primary_elongation: float = 3.0
    min_secondary_length_px: float = 20.0
    min_secondary_inlier_fraction: float = 0.8
    max_primary_paths: int = 500
    max_secondary_paths: int = 500

    def __post_init__(self) -> None:
        direction = np.asarray(self.motion_direction_uv, dtype=float)
        if direction.shape != (2,) or not np.all(np.isfinite(direction)):
            raise ValueError(f"motion_direction_uv must be 2 finite numbers, got {direction}")
        if np.linalg.norm(direction) == 0.0:
            raise ValueError("motion_direction_uv must be non-zero")
        if self.score not in ("unique_rows", "projected_extent"):
            raise ValueError(f"score must be 'unique_rows' or 'projected_extent', got {self.score}")
        positive = {
            "inlier_threshold_px": self.inlier_threshold_px,
            "sample_spacing_px": self.sample_spacing_px,
            "radius_fence_iqr": self.radius_fence_iqr,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be positive, got {value}")
        non_negative = {
            "min_primary_length_px": self.min_primary_length_px,
            "min_primary_elongation": self.min_primary_elongation,
            "min_secondary_length_px": self.min_secondary_length_px,
        }
        for name, value in non_negative.items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be >= 0, got {value}")
        if self.min_samples < 2:
            raise ValueError(f"min_samples must be >= 2, got {self.min_samples}")
        if not 0.0 <= self.min_secondary_inlier_fraction <= 1.0:
            raise ValueError(
                "min_secondary_inlier_fraction must be in [0, 1], got "
                f"{self.min_secondary_inlier_fraction}"
            )
        if self.max_primary_paths < 1 or self.max_secondary_paths < 0:
            raise ValueError(
                "max_primary_paths must be >= 1 and max_secondary_paths >= 0, got "
                f"{self.max_primary_paths} and {self.max_secondary_paths}"
            )


@dataclass(frozen=True)
class Curve2D:
    """One branch curve in the image.

    Attributes:
        curve: Cubic Bezier in pixels; primary: B(0) at the start of the scan direction (bottom
            for upward motion); secondary: B(0) at the junction on the primary's axis.
        samples_px: (K, 2) samples (u, v) along the curve, equally spaced in arc length.
        sample_t: (K,) curve parameters of the samples.
        radii_px: (K,) branch radius in pixels at each sample.
        inside_primary: (K,) True where a secondary's sample lies within the primary's silhouette
            (closer to the primary curve than its radius); skip those when triangulating. Always
            False for the primary.
        score: Search score (primary: see ``Curve2DConfig.score``; secondary: inlier pixels).
        inlier_fraction: Fraction of the pixel path within the inlier threshold of ``curve``.
        pixel_path: (P, 2) int skeleton pixels (u, v) the curve was fitted to, in curve order.
    """

    curve: CubicBezier
    samples_px: np.ndarray
    sample_t: np.ndarray
    radii_px: np.ndarray
    inside_primary: np.ndarray
    score: float
    inlier_fraction: float
    pixel_path: np.ndarray

    @property
    def length_px(self) -> float:
        """Arc length of the curve in pixels."""
        return self.curve.length()


@dataclass(frozen=True)
class MaskCurves:
    """Everything :func:`fit_mask_curves` found in one mask.

    Attributes:
        primary: The primary branch curve, or None when the mask holds no usable branch.
        secondaries: Secondary branch curves, ordered along the primary.
        search_truncated: True when a path search hit its cap (the result may be suboptimal).
        paths_evaluated: Paths fitted over all searches.
        skeleton: The skeleton graph (diagnostics, nearest-skeleton queries).
        mask: (H, W) bool cleaned mask the skeleton came from.
    """

    primary: Curve2D | None
    secondaries: list[Curve2D]
    search_truncated: bool
    paths_evaluated: int
    skeleton: SkeletonGraph
    mask: np.ndarray


@dataclass
class _SearchGraph:
    """The skeleton graph as half-edges: id 2e walks edge e forward, 2e + 1 backward."""

    graph: SkeletonGraph
    pixels: list[np.ndarray]  # per half-edge (P, 2) float pixels in walking order
    radii: list[np.ndarray]  # per half-edge (P,) radii in walking order

    @classmethod
    def build(cls, graph: SkeletonGraph) -> _SearchGraph:
        pixels, radii = [], []
        for edge in graph.edges:
            fwd = edge.pixels_uv.astype(float)
            pixels += [fwd, fwd[::-1]]
            radii += [edge.radii_px, edge.radii_px[::-1]]
        return cls(graph, pixels, radii)

    def head(self, half_edge: int) -> int:
        edge = self.graph.edges[half_edge // 2]
        return edge.start if half_edge % 2 else edge.end

    def tail(self, half_edge: int) -> int:
        return self.head(half_edge ^ 1)

    def path_pixels(self, path: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) pixels and (P,) radii of a half-edge path; shared node pixels appear once."""
        pix = [self.pixels[path[0]]] + [self.pixels[h][1:] for h in path[1:]]
        rad = [self.radii[path[0]]] + [self.radii[h][1:] for h in path[1:]]
        return np.concatenate(pix), np.concatenate(rad)

    def path_nodes(self, path: tuple[int, ...]) -> list[int]:
        return [self.tail(path[0])] + [self.head(h) for h in path]


def _enumerate_paths(
    adjacency: list[list[tuple[int, int]]],
    starts: list[tuple[int, ...]],
    sg: _SearchGraph,
    blocked: set[int],
    max_paths: int,
) -> tuple[list[tuple[int, ...]], bool]:
    """All simple half-edge paths extending the ``starts`` (each start is itself a path).

    Returns:
        The paths (at most ``max_paths``) and whether more were left unexplored.
    """
    paths: list[tuple[int, ...]] = []
    stack = [(start, set(sg.path_nodes(start))) for start in reversed(starts)]
    while stack:
        path, visited = stack.pop()
        if len(paths) == max_paths:
            return paths, True
        paths.append(path)
        for half_edge, nxt in reversed(adjacency[sg.head(path[-1])]):
            if nxt not in visited and nxt not in blocked:
                stack.append(((*path, half_edge), visited | {nxt}))
    return paths, False


def _oriented_adjacency(sg: _SearchGraph, direction: np.ndarray) -> list[list[tuple[int, int]]]:
    """Outgoing half-edges per node, each edge oriented along ``direction`` (a DAG)."""
    progress = sg.graph.node_uv @ direction
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(sg.graph.n_nodes)]
    for e, edge in enumerate(sg.graph.edges):
        # Ties in progress break by node index, so every edge gets one consistent orientation.
        forward = (progress[edge.start], edge.start) < (progress[edge.end], edge.end)
        half_edge = 2 * e if forward else 2 * e + 1
        adjacency[sg.tail(half_edge)].append((half_edge, sg.head(half_edge)))
    return adjacency


def _undirected_adjacency(sg: _SearchGraph, skip_edges: set[int]) -> list[list[tuple[int, int]]]:
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(sg.graph.n_nodes)]
    for e, edge in enumerate(sg.graph.edges):
        if e not in skip_edges:
            adjacency[edge.start].append((2 * e, edge.end))
            adjacency[edge.end].append((2 * e + 1, edge.start))
    return adjacency


class _PrimaryScorer:
    """Scores curves by their skeleton inliers' spread along the motion direction."""

    def __init__(self, graph: SkeletonGraph, direction: np.ndarray, config: Curve2DConfig) -> None:
        progress = graph.pixels_uv @ direction
        order = np.argsort(progress)
        self.pixels = graph.pixels_uv[order].astype(float)
        self.progress = progress[order]
        self.direction = direction
        self.threshold = config.inlier_threshold_px
        self.extent_score = config.score == "projected_extent"
        offset = np.floor(self.progress[0]) if len(order) else 0.0
        self.offset = offset
        self.bins = np.round(self.progress - offset).astype(int)
        occupied = np.zeros(int(self.bins[-1]) + 2 if len(order) else 1, dtype=bool)
        occupied[self.bins] = True
        self.occupied_before = np.concatenate([[0], np.cumsum(occupied)])

    def bound(self, curve: CubicBezier) -> tuple[float, float, float]:
        """Upper bound of the score, and the progress window [lo, hi] holding all inliers."""
        cp_progress = curve.control_points @ self.direction
        lo, hi = cp_progress.min() - self.threshold, cp_progress.max() + self.threshold
        if self.extent_score:
            return hi - lo, lo, hi
        n = len(self.occupied_before) - 1
        first = int(np.clip(np.floor(lo - self.offset), 0, n))
        last = int(np.clip(np.ceil(hi - self.offset) + 1, 0, n))
        return float(self.occupied_before[last] - self.occupied_before[first]), lo, hi

    def score(self, curve: CubicBezier, lo: float, hi: float) -> float:
        first, last = np.searchsorted(self.progress, [lo, hi])
        if last <= first:
            return 0.0
        inliers = curve.closest_params(self.pixels[first:last])[1] <= self.threshold
        if not np.any(inliers):
            return 0.0
        if self.extent_score:
            along = self.progress[first:last][inliers]
            return float(along.max() - along.min())
        return float(len(np.unique(self.bins[first:last][inliers])))


def _robust_radii(radii: np.ndarray, fence_iqr: float) -> np.ndarray:
    """Radii with values beyond the quartile fence replaced by the median."""
    # Linear-interpolation quantiles (numpy's default method), cheaper than np.percentile here.
    ranked = np.sort(radii)
    q1, median, q3 = np.interp(_QUARTILES * (len(ranked) - 1), np.arange(len(ranked)), ranked)
    fence = fence_iqr * (q3 - q1)
    outlier = (radii < q1 - fence) | (radii > q3 + fence)
    return np.where(outlier, median, radii)


def _make_curve2d(
    curve: CubicBezier,
    pixels: np.ndarray,
    radii: np.ndarray,
    score: float,
    inlier_fraction: float,
    config: Curve2DConfig,
) -> Curve2D:
    """Sample a fitted curve and attach radii from its own skeleton path."""
    length = curve.length()
    n_points = max(config.min_samples, math.ceil(length / config.sample_spacing_px) + 1)
    samples, t = curve.resample_by_count(n_points)
    sq = ((samples[:, None, :] - pixels[None, :, :]) ** 2).sum(axis=2)
    sample_radii = _robust_radii(radii[np.argmin(sq, axis=1)], config.radius_fence_iqr)
    return Curve2D(
        curve=curve,
        samples_px=samples,
        sample_t=t,
        radii_px=sample_radii,
        inside_primary=np.zeros(len(t), dtype=bool),
        score=score,
        inlier_fraction=inlier_fraction,
        pixel_path=np.rint(pixels).astype(int),
    )


def _find_primary(
    sg: _SearchGraph, direction: np.ndarray, config: Curve2DConfig
) -> tuple[tuple[int, ...] | None, CubicBezier | None, float, int, bool]:
    """Best-scoring DAG path: (path, curve, score, paths evaluated, truncated)."""
    adjacency = _oriented_adjacency(sg, direction)
    progress = sg.graph.node_uv @ direction
    # Paths start at sources (nodes without incoming edges), lowest first; every prefix counts.
    has_incoming = np.zeros(sg.graph.n_nodes, dtype=bool)
    for out_edges in adjacency:
        for _, head in out_edges:
            has_incoming[head] = True
    starts = [
        (half_edge,)
        for node in np.argsort(progress, kind="stable")
        if not has_incoming[node]
        for half_edge, _ in adjacency[node]
    ]
    paths, truncated = _enumerate_paths(adjacency, starts, sg, set(), config.max_primary_paths)
    # Longest spans first, so that the bound prunes most of the rest.
    along = [pixels @ direction for pixels in sg.pixels]
    low, high = [float(a.min()) for a in along], [float(a.max()) for a in along]
    span = [max(high[h] for h in p) - min(low[h] for h in p) for p in paths]
    scorer = _PrimaryScorer(sg.graph, direction, config)
    best: tuple[tuple[int, ...] | None, CubicBezier | None, float] = (None, None, 0.0)
    for i in np.argsort(span)[::-1]:
        pixels = sg.path_pixels(paths[i])[0]
        if len(pixels) < _MIN_FIT_PIXELS:
            continue
        curve = fit_bezier(pixels)
        bound, lo, hi = scorer.bound(curve)
        if bound <= best[2]:
            continue
        score = scorer.score(curve, lo, hi)
        if score > best[2]:
            best = (paths[i], curve, score)
    return best[0], best[1], best[2], len(paths), truncated


def _find_secondaries(
    sg: _SearchGraph, primary_path: tuple[int, ...], primary: Curve2D, config: Curve2DConfig
) -> tuple[list[Curve2D], int, bool]:
    """Secondary curves off the primary path: (curves, paths evaluated, truncated)."""
    nodes = sg.path_nodes(primary_path)
    primary_nodes = set(nodes)
    adjacency = _undirected_adjacency(sg, {h // 2 for h in primary_path})
    budget, evaluated, truncated = config.max_secondary_paths, 0, False
    found: list[Curve2D] = []
    for junction in nodes[1:-1]:
        for half_edge, other in adjacency[junction]:
            if other in primary_nodes or budget == 0:
                truncated |= budget == 0
                continue
            paths, cut = _enumerate_paths(adjacency, [(half_edge,)], sg, primary_nodes, budget)
            budget -= len(paths)
            evaluated += len(paths)
            truncated |= cut
            best = _best_secondary(sg, paths, config)
            if best is not None:
                found.append(_flag_inside_primary(best, primary))
    return found, evaluated, truncated


def _best_secondary(
    sg: _SearchGraph, paths: list[tuple[int, ...]], config: Curve2DConfig
) -> Curve2D | None:
    """The path with most own-pixel inliers among those with a high inlier rate, if long enough."""
    best, best_score = None, 0.0
    for path in paths:
        pixels, radii = sg.path_pixels(path)
        if len(pixels) < _MIN_FIT_PIXELS:
            continue
        curve = fit_bezier(pixels)
        inliers = curve.closest_params(pixels)[1] <= config.inlier_threshold_px
        score, fraction = float(inliers.sum()), float(inliers.mean())
        if score > best_score and fraction >= config.min_secondary_inlier_fraction:
            best, best_score = (curve, pixels, radii, score, fraction), score
    if best is None or best[0].length() < config.min_secondary_length_px:
        return None
    return _make_curve2d(*best, config)


def _flag_inside_primary(secondary: Curve2D, primary: Curve2D) -> Curve2D:
    t, dist = primary.curve.closest_params(secondary.samples_px)
    radius = np.interp(t, primary.sample_t, primary.radii_px)
    return Curve2D(
        curve=secondary.curve,
        samples_px=secondary.samples_px,
        sample_t=secondary.sample_t,
        radii_px=secondary.radii_px,
        inside_primary=dist < radius,
        score=secondary.score,
        inlier_fraction=secondary.inlier_fraction,
        pixel_path=secondary.pixel_path,
    )


def fit_mask_curves(
    mask: np.ndarray,
    config: Curve2DConfig = Curve2DConfig(),
    motion_direction_uv: np.ndarray | None = None,
) -> MaskCurves:
    """Fit the primary and secondary branch curves of a binary mask.

    Args:
        mask: (H, W) branch mask, bool or {0, 1}.
        config: Fitting parameters (paper defaults).
        motion_direction_uv: Image direction (u, v) of the scan, overriding
            ``config.motion_direction_uv`` (e.g. for a rotated camera).

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
    sg = _SearchGraph.build(graph)
    path, curve, score, evaluated, truncated = _find_primary(sg, direction, config)
    if truncated:
        logger.debug("primary path search truncated after %d paths", evaluated)
    no_primary = MaskCurves(None, [], truncated, evaluated, graph, clean)
    if path is None or curve is None:
        return no_primary
    pixels, radii = sg.path_pixels(path)
    if (curve.control_points[-1] - curve.control_points[0]) @ direction < 0.0:
        # Keep B(0) at the start of the scan direction (a path hooked at its end can flip it).
        curve, pixels, radii = curve.reversed(), pixels[::-1], radii[::-1]
    fraction = float(np.mean(curve.closest_params(pixels)[1] <= config.inlier_threshold_px))
    primary = _make_curve2d(curve, pixels, radii, score, fraction, config)
    if primary.length_px < config.min_primary_length_px or primary.length_px < (
        config.min_primary_elongation * 2.0 * float(primary.radii_px.mean())
    ):
        return no_primary
    secondaries, more, cut = _find_secondaries(sg, path, primary, config)
    return MaskCurves(primary, secondaries, truncated or cut, evaluated + more, graph, clean)


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
