"""2D curve fitting: primary and secondary branch curves from a branch mask (paper section IV-B).

1. Clean the mask and build its skeleton graph (:mod:`recon.skeleton`).
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
   rate) is kept when its curve is at least 20 px long.
5. Sample each curve every 30 px of arc length with the radius of the nearest pixel of its own
   skeleton path; radii beyond the quartile fence are replaced by the median.

Pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from recon.bezier import CubicBezier, fit_bezier
from recon.skeleton import SkeletonConfig, SkeletonGraph, extract_skeleton, preprocess_mask

logger = logging.getLogger(__name__)

_MIN_FIT_PIXELS = 4  # a cubic Bezier has 4 control points
# Newton steps after the dense seed when classifying pixels as inliers: one step from a seed at
# most half a seed spacing (~2.5 px) away leaves errors far below a pixel.
_NEWTON_ITERATIONS = 1
# Inlier prefilter: the curve drawn as a polyline with 4 px segments (sagitta < 0.1 px for
# curvature radii above 20 px) and a band 2 px wider than the threshold on each side (covers
# OpenCV's rounding of thick lines); coordinates with 2 fractional bits.
_RASTER_SEGMENT_PX = 4.0
_RASTER_MIN_PIXELS = 1500  # below this, exact distances for all are cheaper than drawing
_RASTER_MARGIN_PX = 2
_RASTER_SHIFT = 2
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
            (ours: a full or blob-like mask is not a branch; the paper's primary spans the
            220 px tall view with a radius of at most ~16 px, an elongation of ~7).
        min_secondary_length_px: Shortest secondary curve (reference.md: 20 px).
        min_secondary_inlier_fraction: Fewest of a secondary path's pixels within the inlier
            threshold of its curve (ours; the paper asks for an inlier rate "high enough").
        max_secondary_bend_deg: Secondary curves whose tangent turns more than this are
            rejected (ours: a path looping back through a neighbouring side branch is a U).
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
    min_primary_elongation: float = 4.0
    min_secondary_length_px: float = 20.0
    min_secondary_inlier_fraction: float = 0.8
    max_secondary_bend_deg: float = 120.0
    max_primary_paths: int = 100
    max_secondary_paths: int = 100

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
        if not 0.0 < self.max_secondary_bend_deg <= 180.0:
            raise ValueError(
                f"max_secondary_bend_deg must be in (0, 180], got {self.max_secondary_bend_deg}"
            )
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


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class Curve2D:
    """One branch curve in the image.

    Attributes:
        curve: Cubic Bezier in pixels; primary: B(0) at the start of the scan direction (bottom
            for upward motion); secondary: B(0) at the junction on the primary's axis.
        samples_px: (K, 2) samples (u, v) along the curve, equally spaced in arc length.
        radii_px: (K,) branch radius in pixels at each sample.
        score: Search score (primary: see ``Curve2DConfig.score``; secondary: inlier pixels).
        inlier_fraction: Fraction of the pixel path within the inlier threshold of ``curve``.
        pixel_path: (P, 2) int skeleton pixels (u, v) the curve was fitted to, in curve order.
        sample_t: (K,) curve parameters of the samples (found from the samples when None).
        inside_primary: (K,) True where a secondary's sample lies within the primary's silhouette
            (closer to the primary curve than its radius); skip those when triangulating. Always
            False for the primary (and when None).
    """

    curve: CubicBezier
    samples_px: np.ndarray
    radii_px: np.ndarray
    score: float
    inlier_fraction: float
    pixel_path: np.ndarray
    sample_t: np.ndarray | None = None
    inside_primary: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.sample_t is None:
            object.__setattr__(self, "sample_t", self.curve.closest_params(self.samples_px)[0])
        if self.inside_primary is None:
            object.__setattr__(self, "inside_primary", np.zeros(len(self.samples_px), dtype=bool))

    @property
    def length_px(self) -> float:
        """Arc length of the curve in pixels."""
        return self.curve.length()


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class MaskCurves:
    """Everything :func:`fit_mask_curves` found in one mask.

    Attributes:
        primary: The primary branch curve, or None when the mask holds no usable branch.
        secondaries: Secondary branch curves, ordered along the primary.
        search_truncated: True when a path search hit its cap (the result may be suboptimal).
        paths_evaluated: Paths considered over all searches (each fitted and scored, or skipped
            because a score bound showed it could not win).
        skeleton: The skeleton graph (diagnostics, nearest-skeleton queries).
        mask: (H, W) bool cleaned mask the skeleton came from.
    """

    primary: Curve2D | None
    secondaries: list[Curve2D]
    search_truncated: bool
    paths_evaluated: int
    skeleton: SkeletonGraph
    mask: np.ndarray


class _SearchGraph:
    """The skeleton graph as half-edges: id 2e walks edge e forward, 2e + 1 backward."""

    def __init__(self, graph: SkeletonGraph) -> None:
        self.graph = graph
        self._pixels: dict[int, np.ndarray] = {}

    def head(self, half_edge: int) -> int:
        edge = self.graph.edges[half_edge // 2]
        return edge.start if half_edge % 2 else edge.end

    def tail(self, half_edge: int) -> int:
        return self.head(half_edge ^ 1)

    def half_edge_pixels(self, half_edge: int) -> np.ndarray:
        """(P, 2) float pixels of a half-edge in walking order (cached)."""
        pixels = self._pixels.get(half_edge)
        if pixels is None:
            pixels = self.graph.edges[half_edge // 2].pixels_uv.astype(float)
            pixels = pixels[::-1] if half_edge % 2 else pixels
            self._pixels[half_edge] = pixels
        return pixels

    def path_pixels(self, path: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) pixels and (P,) radii of a half-edge path; shared node pixels appear once."""
        pix = [self.half_edge_pixels(path[0])]
        pix += [self.half_edge_pixels(h)[1:] for h in path[1:]]
        rad = [self._radii(path[0])] + [self._radii(h)[1:] for h in path[1:]]
        return np.concatenate(pix), np.concatenate(rad)

    def _radii(self, half_edge: int) -> np.ndarray:
        radii = self.graph.edges[half_edge // 2].radii_px
        return radii[::-1] if half_edge % 2 else radii

    def path_nodes(self, path: tuple[int, ...]) -> list[int]:
        return [self.tail(path[0])] + [self.head(h) for h in path]

    def edge_progress_ranges(self, direction: np.ndarray) -> tuple[list[float], list[float]]:
        """Per edge, the lowest and highest pixel progress along ``direction``."""
        edges = self.graph.edges
        if not edges:
            return [], []
        lengths = np.array([len(e.pixels_uv) for e in edges])
        progress = np.concatenate([e.pixels_uv for e in edges]) @ direction
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        low = np.minimum.reduceat(progress, starts)
        high = np.maximum.reduceat(progress, starts)
        return low.tolist(), high.tolist()


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
    """Scores curves by their skeleton inliers' spread along the motion direction.

    Skeleton pixels are kept sorted by progress (position along the motion direction) so that a
    curve's candidate inliers form one slice. When that slice is large (loopy skeletons), a thick
    polyline drawn into a scratch image first picks the pixels near the curve, and only those get
    exact point-to-curve distances.
    """

    def __init__(self, graph: SkeletonGraph, direction: np.ndarray, config: Curve2DConfig) -> None:
        progress = graph.pixels_uv @ direction
        order = np.argsort(progress)
        self.pixels_uv = graph.pixels_uv[order]
        self.pixels = self.pixels_uv.astype(float)
        self.progress = progress[order]
        self.direction = direction
        self.threshold = config.inlier_threshold_px
        self.extent_score = config.score == "projected_extent"
        self.offset = math.floor(self.progress[0])
        self.bins = np.round(self.progress - self.offset).astype(int)
        occupied = np.zeros(int(self.bins[-1]) + 2, dtype=bool)
        occupied[self.bins] = True
        self.occupied_before = np.concatenate([[0], np.cumsum(occupied)])
        # Scratch image covering the skeleton with a margin for the rasterised band (made lazily).
        self.band_px = math.ceil(self.threshold) + _RASTER_MARGIN_PX
        self.origin = self.pixels_uv.min(axis=0) - self.band_px
        self.canvas_shape = tuple(
            np.flip(self.pixels_uv.max(axis=0) - self.origin + self.band_px + 1)
        )
        self.canvas: np.ndarray | None = None

    def bound_window(self, lo: float, hi: float) -> float:
        """Upper bound of the score of inliers whose progress lies in [lo, hi]."""
        if self.extent_score:
            return hi - lo
        n = len(self.occupied_before) - 1
        first = int(np.clip(math.floor(lo - self.offset), 0, n))
        last = int(np.clip(math.ceil(hi - self.offset) + 1, 0, n))
        return float(self.occupied_before[last] - self.occupied_before[first])

    def curve_window(self, curve: CubicBezier) -> tuple[float, float]:
        """Progress window holding all inliers: the control points' span (the curve lies in
        their convex hull) widened by the inlier threshold."""
        cp_progress = curve.control_points @ self.direction
        return cp_progress.min() - self.threshold, cp_progress.max() + self.threshold

    def score(self, curve: CubicBezier, lo: float, hi: float) -> float:
        first, last = np.searchsorted(self.progress, [lo, hi])
        if last <= first:
            return 0.0
        near = np.arange(first, last)
        if len(near) > _RASTER_MIN_PIXELS:
            near = near[self._near_curve(curve, first, last)]
        dist = curve.closest_params(self.pixels[near], newton_iterations=_NEWTON_ITERATIONS)[1]
        inliers = near[dist <= self.threshold]
        if len(inliers) == 0:
            return 0.0
        if self.extent_score:
            return float(self.progress[inliers[-1]] - self.progress[inliers[0]])
        return float(len(np.unique(self.bins[inliers])))

    def _near_curve(self, curve: CubicBezier, first: int, last: int) -> np.ndarray:
        """(last - first,) True for window pixels inside a band of half width >= threshold + 2."""
        n_points = math.ceil(curve.length() / _RASTER_SEGMENT_PX) + 1
        polyline = curve(np.linspace(0.0, 1.0, n_points)) - self.origin
        fixed = np.rint(polyline * (1 << _RASTER_SHIFT)).astype(np.int32)
        if self.canvas is None:
            self.canvas = np.zeros(self.canvas_shape, dtype=np.uint8)
        self.canvas[:] = 0
        cv2.polylines(
            self.canvas, [fixed], False, 1, 2 * self.band_px + 1, cv2.LINE_8, _RASTER_SHIFT
        )
        uv = self.pixels_uv[first:last] - self.origin
        return self.canvas[uv[:, 1], uv[:, 0]] > 0


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
        radii_px=sample_radii,
        score=score,
        inlier_fraction=inlier_fraction,
        pixel_path=np.rint(pixels).astype(int),
        sample_t=t,
    )


def _component_reach(graph: SkeletonGraph) -> tuple[np.ndarray, np.ndarray]:
    """Connected component of each node, and per component an upper bound of any path's length
    in pixels (a diagonal step, sqrt(2) px, for every pixel step of its edges)."""
    parent = list(range(graph.n_nodes))

    def root(node: int) -> int:
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    for edge in graph.edges:
        parent[root(edge.start)] = root(edge.end)
    component = np.array([root(node) for node in range(graph.n_nodes)], dtype=int)
    steps = [len(edge.pixels_uv) - 1 for edge in graph.edges]
    reach = np.zeros(graph.n_nodes)
    np.add.at(reach, component[[edge.start for edge in graph.edges]], steps)
    return component, reach * math.sqrt(2.0)


def _find_primary(
    sg: _SearchGraph, direction: np.ndarray, config: Curve2DConfig
) -> tuple[tuple[int, ...] | None, CubicBezier | None, float, int, bool]:
    """Best-scoring DAG path: (path, curve, score, paths evaluated, truncated)."""
    adjacency = _oriented_adjacency(sg, direction)
    progress = sg.graph.node_uv @ direction
    has_incoming = np.zeros(sg.graph.n_nodes, dtype=bool)
    for out_edges in adjacency:
        for _, head in out_edges:
            has_incoming[head] = True
    # Paths start at sources (nodes without incoming edges); every prefix counts. Components too
    # small to hold a primary are skipped, and the largest go first, so that speckle cannot use
    # up the path budget before the branch is reached.
    component, reach = _component_reach(sg.graph)
    sources = [
        node
        for node in np.lexsort((progress, -reach[component]))
        if not has_incoming[node] and reach[component[node]] >= config.min_primary_length_px
    ]
    starts = [(half_edge,) for node in sources for half_edge, _ in adjacency[node]]
    paths, truncated = _enumerate_paths(adjacency, starts, sg, set(), config.max_primary_paths)
    if not paths:
        return None, None, 0.0, 0, truncated
    low, high = sg.edge_progress_ranges(direction)
    extent = [(min(low[h // 2] for h in p), max(high[h // 2] for h in p)) for p in paths]
    scorer = _PrimaryScorer(sg.graph, direction, config)
    # Widest paths first, so that the bounds skip most of the rest: a path whose pixels (widened
    # by twice the threshold) cannot beat the best is not fitted; a fitted curve whose control
    # points cannot beat it is not scored.
    margin = 2.0 * config.inlier_threshold_px
    best: tuple[tuple[int, ...] | None, CubicBezier | None, float] = (None, None, 0.0)
    best_residual: float | None = None
    for i in np.argsort([hi - lo for lo, hi in extent], kind="stable")[::-1]:
        lo, hi = extent[i]
        if scorer.bound_window(lo - margin, hi + margin) < best[2]:
            continue
        pixels = sg.path_pixels(paths[i])[0]
        if len(pixels) < _MIN_FIT_PIXELS:
            continue
        curve = fit_bezier(pixels)
        lo, hi = scorer.curve_window(curve)
        if scorer.bound_window(lo, hi) < best[2]:
            continue
        score = scorer.score(curve, lo, hi)
        if score > best[2]:
            best, best_residual = (paths[i], curve, score), None
        elif score == best[2] and score > 0.0:
            # Ties (e.g. the trunk and a side branch both reaching the top of the view) go to
            # the path its curve fits best: the smallest RMS distance of its own pixels.
            if best_residual is None:
                best_residual = _rms_residual(best[1], sg.path_pixels(best[0])[0])
            residual = _rms_residual(curve, pixels)
            if residual < best_residual:
                best, best_residual = (paths[i], curve, score), residual
    return best[0], best[1], best[2], len(paths), truncated


def _rms_residual(curve: CubicBezier, pixels: np.ndarray) -> float:
    """RMS distance in pixels of (P, 2) pixels to the curve."""
    dist = curve.closest_params(pixels, newton_iterations=_NEWTON_ITERATIONS)[1]
    return float(np.sqrt(np.mean(dist**2)))


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
                found.append(best)
    return _flag_inside_primary(found, primary), evaluated, truncated


def _best_secondary(
    sg: _SearchGraph, paths: list[tuple[int, ...]], config: Curve2DConfig
) -> Curve2D | None:
    """The path with most own-pixel inliers among those with a high inlier rate and a limited
    bend, if its curve is long enough."""
    best, best_score = None, 0.0
    for path in paths:
        pixels, radii = sg.path_pixels(path)
        if len(pixels) < _MIN_FIT_PIXELS:
            continue
        curve = fit_bezier(pixels)
        dist = curve.closest_params(pixels, newton_iterations=_NEWTON_ITERATIONS)[1]
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
    return _make_curve2d(*best, config)


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
    sg = _SearchGraph(graph)
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
    dist = curve.closest_params(pixels, newton_iterations=_NEWTON_ITERATIONS)[1]
    fraction = float(np.mean(dist <= config.inlier_threshold_px))
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
