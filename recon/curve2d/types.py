"""2D curve fitting's configuration and results: :class:`Curve2DConfig`, :class:`Curve2D`,
:class:`MaskCurves`, and :func:`make_curve2d`, which samples a fitted Bezier into a
:class:`Curve2D` with radii from its own skeleton path (paper section IV-B; see
``recon/curve2d/fit.py`` for the algorithm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from recon.curve2d.skeleton import SkeletonConfig
from recon.curve2d.skeleton_graph import SkeletonGraph
from recon.geometry.bezier import CubicBezier
from recon.validation import require_non_negative, require_positive

MIN_FIT_PIXELS = 4  # a cubic Bezier has 4 control points
# Newton steps after the dense seed when classifying pixels as inliers: one step from a seed at
# most half a seed spacing (~2.5 px) away leaves errors far below a pixel.
NEWTON_ITERATIONS = 1
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
        sample_spacing_px: Arc-length spacing of the primary curve's samples (paper IV-A: 30 px).
        secondary_sample_spacing_px: Arc-length spacing of a secondary curve's samples (ours:
            at the paper's 30 px a 65 px side branch gets 3 samples, the one at the junction lies
            inside the primary and the other two are too few to lift: measured, such candidates
            never entered the model; 10 px gives a 40 px branch 4 liftable samples).
        min_samples: Fewest samples per curve; short curves are sampled more densely (ours: a
            3D curve needs a start, a middle and an end).
        secondary_min_samples: Fewest samples per secondary curve (ours: the samples within the
            primary's silhouette are not lifted, and a detection needs 3 lifted points; measured,
            30 px candidates of branches seen over 800-2000 px kept only 2 at 10 px spacing).
        radius_fence_iqr: Radii beyond this many interquartile ranges outside the quartiles are
            replaced by the median (reference.md: the quartile fence, 1.5).
        min_primary_length_px: Shorter best primary curves are rejected (ours: speckle noise
            yields short, well-fitting fragments; the paper's primary spans the view).
        min_primary_elongation: Reject a primary whose length is below this many mean diameters
            (ours: a full or blob-like mask is not a branch; the paper's primary spans the
            220 px tall view with a radius of at most ~16 px, an elongation of ~7).
        primary_view_span: A primary whose pixels span at least this fraction of the view's
            interior along the scan direction passes the elongation test whatever its width, if
            it is at most ``max_spanning_width`` of the interior across it (ours: a trunk close
            to the camera is wider than a fifth of its length in view and is still a branch; in
            the orchard world, trunks of 27-33 px radius filling the 220 px tall view were
            rejected and the scans lost; a blob does not cross the view, a full mask is wider).
        max_spanning_width: Widest such primary, as a fraction of the interior's width across
            the scan direction (ours: half the view).
        max_primary_turn_deg: A path that turns by more than this at one of its skeleton
            junctions (its chord over the 30 px before the junction against the one over the
            30 px after it, ``recon/curve2d/primary.py``) is no primary candidate; its part
            before the turn still is. ``inf``: no limit, the paper's rule. On single real
            frames the paper's score takes the trunk's path up into a side branch that
            reaches the top edge higher than the trunk's cut end (issue 61); a trunk bends
            gently, a side branch leaves at 30-90 deg.
        spanning_min_inlier_fraction: Fewest of such a primary's skeleton pixels within the
            inlier threshold of its curve (ours: a wide trunk's skeleton is smooth, ~1.0; the
            skeleton of a 50 % speckle mask that crosses the view, 0.86).
        min_secondary_length_px: Shortest secondary curve (reference.md: 20 px).
        min_secondary_inlier_fraction: Fewest of a secondary path's pixels within the inlier
            threshold of its curve (ours; the paper asks for an inlier rate "high enough").
        max_secondary_bend_deg: Secondary curves whose tangent turns more than this are
            rejected (ours: a path looping back through a neighbouring side branch is a U).
        extend_secondary_tips: Extend each secondary's skeleton path at its free tip along its
            end tangent to the silhouette's end (ours: thinning stops about a radius short, which
            a receding branch turns into centimetres of missing length).
        tip_tangent_px: Arc length over which the end tangent is measured (ours).
        tip_extension_radii: Longest tip extension, in tip radii (ours: a skeleton ends about
            one radius inside a round or flat end; two allow for its end hook).
        crossing_level_px: An edge of the skeleton between two junctions whose ends lie within
            this distance of each other along the motion direction may be walked both ways by
            the primary search (ours: the inlier threshold's 4 px; 0 orients every edge). Where
            side branches leave the primary on both sides at about one height, the skeleton
            splits the crossing into two junctions joined by a short level edge; oriented one
            way, it cuts the straight primary path in two and an L-shaped path (primary, then a
            side branch) wins (measured, tree 40: restarts onto a side branch during a
            rotation, then the primary lost).
        max_primary_paths: Cap on DAG paths examined for the primary (ours: bounds the search
            that is exponential in skeleton loops).
        max_secondary_paths: Cap on paths examined for all secondaries together (ours).
    """

    skeleton: SkeletonConfig = field(default_factory=SkeletonConfig)
    motion_direction_uv: tuple[float, float] = (0.0, -1.0)
    inlier_threshold_px: float = 4.0
    score: Literal["unique_rows", "projected_extent"] = "unique_rows"
    sample_spacing_px: float = 30.0
    secondary_sample_spacing_px: float = 10.0
    min_samples: int = 3
    secondary_min_samples: int = 7
    radius_fence_iqr: float = 1.5
    min_primary_length_px: float = 40.0
    min_primary_elongation: float = 4.0
    primary_view_span: float = 0.9
    max_spanning_width: float = 0.5
    max_primary_turn_deg: float = math.inf
    spanning_min_inlier_fraction: float = 0.95
    min_secondary_length_px: float = 20.0
    min_secondary_inlier_fraction: float = 0.8
    max_secondary_bend_deg: float = 120.0
    extend_secondary_tips: bool = True
    tip_tangent_px: float = 10.0
    tip_extension_radii: float = 2.0
    crossing_level_px: float = 4.0
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
        require_positive(
            self,
            "inlier_threshold_px",
            "sample_spacing_px",
            "secondary_sample_spacing_px",
            "radius_fence_iqr",
            "tip_tangent_px",
        )
        require_non_negative(self, "tip_extension_radii", "crossing_level_px")
        require_non_negative(
            self, "min_primary_length_px", "min_primary_elongation", "min_secondary_length_px"
        )
        for name in ("primary_view_span", "max_spanning_width", "spanning_min_inlier_fraction"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not 0.0 < self.max_primary_turn_deg <= math.inf:
            raise ValueError(
                f"max_primary_turn_deg must be > 0 (inf: no limit), got {self.max_primary_turn_deg}"
            )
        if not 0.0 < self.max_secondary_bend_deg <= 180.0:
            raise ValueError(
                f"max_secondary_bend_deg must be in (0, 180], got {self.max_secondary_bend_deg}"
            )
        if self.min_samples < 2 or self.secondary_min_samples < 2:
            raise ValueError(
                "min_samples and secondary_min_samples must be >= 2, got "
                f"{self.min_samples} and {self.secondary_min_samples}"
            )
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
        bridged: (K,) True where a sample lies on a bridged gap of the mask (off the mask,
            ``recon/curve2d/skeleton_bridge.py``); skip those when triangulating. All False
            when None.
    """

    curve: CubicBezier
    samples_px: np.ndarray
    radii_px: np.ndarray
    score: float
    inlier_fraction: float
    pixel_path: np.ndarray
    sample_t: np.ndarray | None = None
    inside_primary: np.ndarray | None = None
    bridged: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.sample_t is None:
            object.__setattr__(self, "sample_t", self.curve.closest_params(self.samples_px)[0])
        if self.inside_primary is None:
            object.__setattr__(self, "inside_primary", np.zeros(len(self.samples_px), dtype=bool))
        if self.bridged is None:
            object.__setattr__(self, "bridged", np.zeros(len(self.samples_px), dtype=bool))

    @property
    def liftable(self) -> np.ndarray:
        """(K,) True for the samples to triangulate: on the mask, outside the primary."""
        return ~(np.asarray(self.inside_primary, bool) | np.asarray(self.bridged, bool))

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


def _robust_radii(radii: np.ndarray, fence_iqr: float) -> np.ndarray:
    """Radii with values beyond the quartile fence replaced by the median."""
    # Linear-interpolation quantiles (numpy's default method), cheaper than np.percentile here.
    ranked = np.sort(radii)
    q1, median, q3 = np.interp(_QUARTILES * (len(ranked) - 1), np.arange(len(ranked)), ranked)
    fence = fence_iqr * (q3 - q1)
    outlier = (radii < q1 - fence) | (radii > q3 + fence)
    return np.where(outlier, median, radii)


def make_curve2d(
    curve: CubicBezier,
    pixels: np.ndarray,
    radii: np.ndarray,
    score: float,
    inlier_fraction: float,
    config: Curve2DConfig,
    spacing_px: float | None = None,
    min_samples: int | None = None,
) -> Curve2D:
    """Sample a fitted curve and attach radii from its own skeleton path.

    Args:
        curve: The fitted curve.
        pixels: (P, 2) skeleton pixels it was fitted to, in curve order.
        radii: (P,) radius of each pixel.
        score: Search score.
        inlier_fraction: Fraction of ``pixels`` within the inlier threshold.
        config: Sampling and radius options.
        spacing_px: Arc-length sample spacing (default ``config.sample_spacing_px``).
        min_samples: Fewest samples (default ``config.min_samples``).
    """
    spacing = config.sample_spacing_px if spacing_px is None else spacing_px
    fewest = config.min_samples if min_samples is None else min_samples
    length = curve.length()
    n_points = max(fewest, math.ceil(length / spacing) + 1)
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
