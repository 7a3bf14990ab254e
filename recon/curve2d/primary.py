"""Primary curve search of the 2D curve fitting (``recon/curve2d/fit.py``, step 3).

:func:`find_primary` searches the DAG's directed paths from its sources, fits a cubic Bezier to
each and scores it by its skeleton inliers' spread along the motion direction
(:class:`_PrimaryScorer`), skipping paths whose score bounds cannot beat the best.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from recon.curve2d.path_search import (
    SearchGraph,
    component_reach,
    enumerate_paths,
    oriented_adjacency,
)
from recon.curve2d.skeleton_graph import SkeletonGraph
from recon.curve2d.types import MIN_FIT_PIXELS, NEWTON_ITERATIONS, Curve2DConfig
from recon.geometry.bezier import CubicBezier
from recon.geometry.bezier_fit import fit_bezier

# Inlier prefilter: the curve drawn as a polyline with 4 px segments (sagitta < 0.1 px for
# curvature radii above 20 px) and a band 2 px wider than the threshold on each side (covers
# OpenCV's rounding of thick lines); coordinates with 2 fractional bits.
_RASTER_SEGMENT_PX = 4.0
_RASTER_MIN_PIXELS = 1500  # below this, exact distances for all are cheaper than drawing
_RASTER_MARGIN_PX = 2
_RASTER_SHIFT = 2
# PrimaryPrior.turns_away (ours): the model's direction over its last 30 px of projection (the
# paper's primary sample spacing), the curve's run over the next 40 px (past a junction's blob),
# the curve sampled every ~1/64 of its length; a model chord shorter than 8 px gives no direction.
_TURN_BASE_PX = 30.0
_TURN_LOOKAHEAD_PX = 40.0
_TURN_MIN_CHORD_PX = 8.0
_TURN_SAMPLES = 65
# Curve2DConfig.max_primary_turn_deg (ours): a path's run before and after a junction is its
# chord over 30 px of it (the paper's primary sample spacing; past a junction's blob); a side
# with less than half that is too short to tell a direction.
_JUNCTION_CHORD_PX = 30.0


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
        dist = curve.closest_params(self.pixels[near], newton_iterations=NEWTON_ITERATIONS)[1]
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


@dataclass(frozen=True)
class PrimaryPrior:
    """Where the 3D model says the primary is: its visible points projected into this frame.

    Attributes:
        pixels: (K, 2) projected model points (u, v), base to top of the model.
        tolerance_px: A model point agrees with a curve within this distance (paper IV: 4 px).
        min_fraction: A curve agrees with the model when this fraction of points does (60 %).
        max_turn_deg: Largest angle between the model's direction at its last visible point and
            the curve's run beyond it (:meth:`turns_away`); ``inf``: no limit (the paper's rule).
        vouches: A curve that agrees with the model is a primary however short (down to
            ``Curve2DConfig.min_primary_length_px``): the elongation and view-span tests, which
            keep blobs from starting a model, are skipped for it.
    """

    pixels: np.ndarray
    tolerance_px: float
    min_fraction: float
    max_turn_deg: float = math.inf
    vouches: bool = False

    def agreement(self, curve: CubicBezier) -> float:
        """Fraction of the model points within ``tolerance_px`` of ``curve``."""
        dist = curve.closest_params(self.pixels, newton_iterations=NEWTON_ITERATIONS)[1]
        return float(np.mean(dist <= self.tolerance_px))

    def agrees(self, curve: CubicBezier) -> bool:
        """Whether ``curve`` agrees with the model (``min_fraction`` of its points)."""
        return self.agreement(curve) >= self.min_fraction

    def turns_away(self, curve: CubicBezier) -> bool:
        """Whether ``curve`` agrees with the model but leaves it at an angle above ``max_turn_deg``.

        Such a curve follows the model up to its last visible point and then takes another
        branch: where the primary's mask is cut (an occluder, a gap in a learned mask), a side
        branch leaving near the cut, or a crossing neighbour branch, is the longest path through
        the model's pixels, and taking it moves the model off the primary. The model's direction
        is the chord over its last ``_TURN_BASE_PX`` of projection; the curve's run is its chord
        between where it crosses the model's end and ``_TURN_LOOKAHEAD_PX`` beyond it (progress
        along the model's direction). A curve that does not reach half that far beyond the end
        does not turn away.
        """
        if not math.isfinite(self.max_turn_deg) or len(self.pixels) < 2:
            return False
        end = self.pixels[-1]
        far = np.flatnonzero(np.linalg.norm(self.pixels - end, axis=1) >= _TURN_BASE_PX)
        model = end - (self.pixels[far[-1]] if len(far) else self.pixels[0])
        length = float(np.linalg.norm(model))
        if length < _TURN_MIN_CHORD_PX:
            return False
        model /= length
        samples = curve(np.linspace(0.0, 1.0, _TURN_SAMPLES))
        along = (samples - end) @ model
        ahead = np.flatnonzero((along >= 0.0) & (along <= _TURN_LOOKAHEAD_PX))
        if len(ahead) < 2 or np.ptp(along[ahead]) < 0.5 * _TURN_LOOKAHEAD_PX:
            return False
        run = samples[ahead[np.argmax(along[ahead])]] - samples[ahead[np.argmin(along[ahead])]]
        cos_turn = float(run @ model) / float(np.linalg.norm(run))
        return cos_turn < math.cos(math.radians(self.max_turn_deg)) and self.agrees(curve)


def find_primary(
    sg: SearchGraph,
    direction: np.ndarray,
    config: Curve2DConfig,
    prior: PrimaryPrior | None = None,
) -> tuple[tuple[int, ...] | None, CubicBezier | None, float, int, bool]:
    """Best-scoring DAG path: (path, curve, score, paths evaluated, truncated).

    With a ``prior`` (the projected 3D model), when the best-scoring curve disagrees with the
    model but another path agrees, the best-scoring path among those that agree is chosen: a side
    branch that rises along the view after a rotation must not replace a well-supported primary.
    Without an agreeing path the plain best is returned (and the modeler finds it Inconsistent).
    A curve that agrees with the prior but turns away from it beyond its last visible point
    (:meth:`PrimaryPrior.turns_away`, when ``prior.max_turn_deg`` is finite) is never chosen.
    """
    adjacency = oriented_adjacency(sg, direction, config.crossing_level_px)
    progress = sg.graph.node_uv @ direction
    has_incoming = np.zeros(sg.graph.n_nodes, dtype=bool)
    for out_edges in adjacency:
        for _, head in out_edges:
            has_incoming[head] = True
    # Paths start at sources (nodes without incoming edges); every prefix counts. Components too
    # small to hold a primary are skipped, and the largest go first, so that speckle cannot use
    # up the path budget before the branch is reached.
    component, reach = component_reach(sg.graph)
    sources = [
        node
        for node in np.lexsort((progress, -reach[component]))
        if not has_incoming[node] and reach[component[node]] >= config.min_primary_length_px
    ]
    starts = [(half_edge,) for node in sources for half_edge, _ in adjacency[node]]
    paths, truncated = enumerate_paths(adjacency, starts, sg, set(), config.max_primary_paths)
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
        if len(pixels) < MIN_FIT_PIXELS:
            continue
        if math.isfinite(config.max_primary_turn_deg) and _turns_at_a_junction(
            sg, paths[i], pixels, config.max_primary_turn_deg
        ):
            continue  # the trunk's path bending into a side branch: its prefix is a candidate
        curve = fit_bezier(pixels)
        lo, hi = scorer.curve_window(curve)
        if scorer.bound_window(lo, hi) < best[2]:
            continue
        score = scorer.score(curve, lo, hi)
        if score >= best[2] and score > 0.0 and prior is not None and prior.turns_away(curve):
            continue  # follows the model, then leaves it for another branch
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
    if prior is not None and best[1] is not None and not prior.agrees(best[1]):
        agreeing = _best_agreeing_path(sg, paths, scorer, prior)
        if agreeing is not None:
            best = agreeing
    return best[0], best[1], best[2], len(paths), truncated


def _turns_at_a_junction(
    sg: SearchGraph, path: tuple[int, ...], pixels: np.ndarray, max_turn_deg: float
) -> bool:
    """Whether a path turns by more than ``max_turn_deg`` at one of its inner nodes.

    At each node between two of the path's edges, the path's run before it (the chord from
    the last pixel at least ``_JUNCTION_CHORD_PX`` back to the node) is compared with its run
    after it (the chord to the first pixel that far ahead); a side shorter than half that is
    not judged.

    Args:
        sg: The search graph.
        path: Half-edge ids.
        pixels: (P, 2) the path's pixels (``sg.path_pixels(path)[0]``).
        max_turn_deg: Largest turn allowed.
    """
    if len(path) < 2:
        return False
    cos_limit = math.cos(math.radians(max_turn_deg))
    node_index = np.cumsum([len(sg.half_edge_pixels(h)) - 1 for h in path])[:-1]
    for index in node_index:
        node = pixels[index]
        before = np.linalg.norm(pixels[:index] - node, axis=1)
        after = np.linalg.norm(pixels[index + 1 :] - node, axis=1)
        if len(before) == 0 or len(after) == 0:
            continue
        if before.max() < 0.5 * _JUNCTION_CHORD_PX or after.max() < 0.5 * _JUNCTION_CHORD_PX:
            continue
        far_before = np.flatnonzero(before >= min(_JUNCTION_CHORD_PX, before.max()))[-1]
        far_after = np.flatnonzero(after >= min(_JUNCTION_CHORD_PX, after.max()))[0]
        incoming = node - pixels[far_before]
        outgoing = pixels[index + 1 + far_after] - node
        cos_turn = float(incoming @ outgoing) / float(
            np.linalg.norm(incoming) * np.linalg.norm(outgoing)
        )
        if cos_turn < cos_limit:
            return True
    return False


def _best_agreeing_path(
    sg: SearchGraph, paths: list[tuple[int, ...]], scorer: _PrimaryScorer, prior: PrimaryPrior
) -> tuple[tuple[int, ...], CubicBezier, float] | None:
    """Highest-scoring path whose curve agrees with the prior (no bound pruning: all are fitted)."""
    best = None
    for path in paths:
        pixels = sg.path_pixels(path)[0]
        if len(pixels) < MIN_FIT_PIXELS:
            continue
        curve = fit_bezier(pixels)
        if not prior.agrees(curve) or prior.turns_away(curve):
            continue
        score = scorer.score(curve, *scorer.curve_window(curve))
        if best is None or score > best[2]:
            best = (path, curve, score)
    return best


def _rms_residual(curve: CubicBezier, pixels: np.ndarray) -> float:
    """RMS distance in pixels of (P, 2) pixels to the curve."""
    dist = curve.closest_params(pixels, newton_iterations=NEWTON_ITERATIONS)[1]
    return float(np.sqrt(np.mean(dist**2)))
