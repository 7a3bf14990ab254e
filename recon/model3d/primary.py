"""The primary branch: consistency check against a mask and the 3D refit of its visible part.

The model is an ordered polyline (bottom to top) with a radius per point. Each Consistent
iteration replaces the part that projects into the current image by a cubic Bezier fitted (RANSAC,
paper IV) to the surviving model points there plus the newly lifted points, resampled ~30 px apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.camera import project_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.geometry.bezier import CubicBezier
from recon.geometry.bezier_fit import ransac_fit_bezier
from recon.model import BranchModel


@dataclass
class ProjectedModel:
    """Model points seen from one frame.

    Attributes:
        pixels: (N, 2) projections (NaN behind the camera).
        depth_m: (N,) camera-frame depths.
        visible: (N,) in front of the camera and inside the image margin.
        near_curve: (N,) visible, inside the mask and within tolerance of the 2D curve.
    """

    pixels: np.ndarray
    depth_m: np.ndarray
    visible: np.ndarray
    near_curve: np.ndarray

    @property
    def consistent_fraction(self) -> float:
        """Fraction of visible points that agree with the mask (NaN when none are visible)."""
        n = int(self.visible.sum())
        return float(self.near_curve.sum() / n) if n else float("nan")


def project_model(
    points: np.ndarray, frame: Frame, curve_2d: CubicBezier, config: ModelerConfig
) -> ProjectedModel:
    """Project model points into ``frame`` and compare them with the mask's 2D primary curve."""
    pixels, depth = project_points(points, frame.T_world_camera, frame.intrinsics)
    visible = (depth > 0) & frame.intrinsics.in_image(pixels, config.image_margin_px)
    near = np.zeros(len(points), dtype=bool)
    if visible.any():
        px = pixels[visible]
        rows = np.clip(np.rint(px[:, 1]).astype(int), 0, frame.intrinsics.height - 1)
        cols = np.clip(np.rint(px[:, 0]).astype(int), 0, frame.intrinsics.width - 1)
        _, dist = curve_2d.closest_params(px)
        near[visible] = frame.mask[rows, cols] & (dist <= config.consistency_tolerance_px)
    return ProjectedModel(pixels, depth, visible, near)


def robust_radius_profile(t: np.ndarray, radii: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Radii at ``t_out`` from noisy (t, radius) samples: quartile-fence outlier removal, a line.

    A branch tapers slowly, so over one view its radius is close to linear in the curve parameter.
    """
    q1, q3 = np.percentile(radii, [25, 75])
    fence = 1.5 * (q3 - q1)
    keep = (radii >= q1 - fence) & (radii <= q3 + fence)
    t, radii = t[keep], radii[keep]
    if len(radii) >= 4 and np.ptp(t) > 0.2:
        slope, intercept = np.polyfit(t, radii, 1)
        out = slope * t_out + intercept
        lo, hi = radii.min(), radii.max()
        return np.clip(out, lo, hi)
    return np.full(len(t_out), float(np.median(radii)))


def fit_visible_segment(
    points: np.ndarray,
    radii: np.ndarray,
    frame: Frame,
    config: ModelerConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """RANSAC-fit the visible primary and resample it ~``primary_spacing_px`` apart.

    Args:
        points: (N, 3) centre points ordered bottom to top (along the image's up direction).
        radii: (N,) radii in metres.
        frame: The current frame (for the sample spacing in metres at the branch's depth).
        config: RANSAC thresholds.
        rng: Random generator for RANSAC.

    Returns:
        (K, 3) resampled centerline, (K,) radii and the inlier fraction, or None when there are
        too few points or fewer than ``ransac_min_inlier_fraction`` inliers (an Inconsistent frame).
    """
    if len(points) < config.min_lifted_points:
        return None
    fit = ransac_fit_bezier(
        points,
        inlier_threshold=config.ransac_inlier_m,
        min_inlier_fraction=config.ransac_min_inlier_fraction,
        rng=rng,
        iterations=config.ransac_iterations,
    )
    if fit is None:
        return None
    inlier_points = points[fit.inliers]
    t_in, _ = fit.curve.closest_params(inlier_points)
    t_lo, t_hi = float(t_in.min()), float(t_in.max())
    depth = np.median(
        np.linalg.norm(inlier_points - frame.T_world_camera[:3, 3], axis=1)
    )  # distance to the branch, metres
    spacing_m = config.primary_spacing_px * depth / frame.intrinsics.fx
    segment = _sub_curve(fit.curve, t_lo, t_hi)
    samples, t_seg = segment.resample_by_arclength(max(spacing_m, 1e-4))
    t_out = t_lo + t_seg * (t_hi - t_lo)
    seg_radii = robust_radius_profile(t_in, radii[fit.inliers], t_out)
    return samples, seg_radii, fit.inlier_fraction


def splice(
    model: BranchModel | None,
    replace: np.ndarray,
    segment: np.ndarray,
    segment_radii: np.ndarray,
    up_world: np.ndarray,
) -> BranchModel:
    """Replace the ``replace``-flagged model points by ``segment``, keeping bottom-to-top order.

    Args:
        model: Current primary, or None.
        replace: (N,) flags of model points the segment replaces (the visible ones).
        segment: (K, 3) new points; flipped if needed so that they run along ``up_world``.
        segment_radii: (K,) radii.
        up_world: (3,) the scan direction in the world frame (the image's up direction).
    """
    if np.dot(segment[-1] - segment[0], up_world) < 0:
        segment, segment_radii = segment[::-1], segment_radii[::-1]
    if model is None or len(model.points) == 0:
        return BranchModel(segment, segment_radii)
    keep = ~replace
    heights = model.points @ up_world
    seg_lo, seg_hi = segment[0] @ up_world, segment[-1] @ up_world
    below = keep & (heights < seg_lo)
    above = keep & (heights > seg_hi)
    points = np.concatenate([model.points[below], segment, model.points[above]])
    radii = np.concatenate([model.radii[below], segment_radii, model.radii[above]])
    return BranchModel(points, radii, branch_id=model.branch_id, trust=model.trust)


def _sub_curve(curve: CubicBezier, t0: float, t1: float) -> CubicBezier:
    """The part of ``curve`` between parameters t0 < t1, as a cubic Bezier."""
    ts = np.linspace(t0, t1, 4)
    # A cubic's restriction is a cubic: interpolate it through 4 points at its own parameters.
    basis = _bernstein(np.linspace(0.0, 1.0, 4))
    control = np.linalg.solve(basis, curve(ts))
    return CubicBezier(control)


def _bernstein(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, float)[:, None]
    k = np.arange(4)[None, :]
    coeff = np.array([1.0, 3.0, 3.0, 1.0])[None, :]
    return coeff * t**k * (1.0 - t) ** (3 - k)
