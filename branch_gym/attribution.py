"""Why a side branch was missed: how well the scan's views showed it (simulation only).

During a scan :class:`BranchVisibility` counts, in every rendered frame, the instance-label pixels
of each ground-truth secondary outside the primary's silhouette. The labels are a visibility
render: a branch hidden behind the primary shows only the pixels that stick out of it. A branch in
front of the primary covers it, and the mask, one class for both, cannot tell them apart there:
only its pixels outside the silhouette the primary has on its own (drawn from the ground truth)
count. It keeps, per branch, the most pixels any frame showed and the camera's rotation about the
branch then.

:func:`branch_rows` turns that and the metrics into one row per ground-truth secondary and
classifies each miss:

==================  ===========================================================================
``never_seen``      no frame showed ``seen_min_pixels`` of it: the viewpoints' fault, what a
                    rotation policy must fix
``seen``            a frame showed it well and the model still lacks it: perception's fault
==================  ===========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from branch_gym.control import heading_rad
from branch_gym.sim.scene.tree_scene import FIRST_SECONDARY_LABEL
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.sim.validation import require_positive
from recon.camera import CameraIntrinsics, project_points
from recon.metrics import TreeMetrics

MISS_SEEN = "seen"
MISS_NEVER_SEEN = "never_seen"
_MM_PER_M = 1e3


@dataclass(frozen=True)
class AttributionConfig:
    """When a branch counts as seen.

    Attributes:
        seen_min_pixels: Visible pixels in one frame that make a branch seen (our choice: 300,
            a 2D candidate of the paper's minimum length, 20 px, at the apparent width of a
            4 mm branch at z_target, ~16 px: anything smaller the 2D stage drops by design).
        silhouette_margin_px: The primary's silhouette is drawn this much wider than its
            projected radius (our choice: the renderer's edge pixels).
    """

    seen_min_pixels: int = 300
    silhouette_margin_px: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, "seen_min_pixels", "silhouette_margin_px")


class BranchVisibility:
    """Per ground-truth secondary: the most pixels outside the primary's silhouette in any frame
    and the view angle then.

    Args:
        intrinsics: The rendering camera's intrinsics (to draw the primary's silhouette).
        config: The silhouette margin.

    Attributes:
        peak_pixels: (G,) most visible pixels of each secondary outside the primary's silhouette
            in one frame.
        peak_view_angle_deg: (G,) the camera's yaw from its home heading in that frame (deg,
            NaN while never visible).
        frames: Frames observed.
    """

    def __init__(
        self,
        intrinsics: CameraIntrinsics | None = None,
        config: AttributionConfig | None = None,
    ) -> None:
        self.intrinsics = intrinsics or CameraIntrinsics.from_fov()
        self.config = config or AttributionConfig()
        self.reset(0, np.eye(4))

    def reset(
        self,
        n_secondaries: int,
        T_world_camera_home: np.ndarray,
        primary: BranchGT | None = None,
    ) -> None:
        """Start a scan of a tree with ``n_secondaries`` secondaries from the home pose.

        Args:
            n_secondaries: Ground-truth secondaries of the tree.
            T_world_camera_home: (4, 4) camera pose at the start (the rotation reference).
            primary: The tree's ground-truth primary; None counts every label pixel.
        """
        self.peak_pixels = np.zeros(n_secondaries, np.int64)
        self.peak_view_angle_deg = np.full(n_secondaries, np.nan)
        self.frames = 0
        self._home_heading_rad = heading_rad(T_world_camera_home)
        self._primary = primary

    def observe(self, labels: np.ndarray, T_world_camera: np.ndarray) -> None:
        """Count each secondary's pixels outside the primary's silhouette in one rendered (H, W)
        instance-label image."""
        self.frames += 1
        n = len(self.peak_pixels)
        if n == 0:
            return
        pixels = _secondary_pixel_counts(labels, n)
        if self._primary is not None and np.any(pixels > self.peak_pixels):
            # Only then can a count outside the silhouette (never more) beat a peak.
            outside = labels[~self.primary_silhouette(T_world_camera)]
            pixels = _secondary_pixel_counts(outside, n)
        better = pixels > self.peak_pixels
        if better.any():
            turned = math.remainder(heading_rad(T_world_camera) - self._home_heading_rad, math.tau)
            self.peak_pixels[better] = pixels[better]
            self.peak_view_angle_deg[better] = math.degrees(turned)

    def primary_silhouette(self, T_world_camera: np.ndarray) -> np.ndarray:
        """(H, W) bool: the ground-truth primary's silhouette, as if nothing covered it.

        Discs of the projected radius (plus ``silhouette_margin_px``) at every centerline point
        in front of the camera: a tube seen from the side (the dense ground truth is ~1 mm, a
        few pixels, apart).
        """
        intrinsics = self.intrinsics
        silhouette = np.zeros((intrinsics.height, intrinsics.width), np.uint8)
        if self._primary is None:
            return silhouette.astype(bool)
        pixels, depth = project_points(self._primary.points, T_world_camera, intrinsics)
        radius_px = intrinsics.fx * self._primary.radii / np.maximum(depth, 1e-9)
        radius_px += self.config.silhouette_margin_px
        reach = radius_px + 1.0
        near = (
            (depth > 0)
            & (pixels[:, 0] > -reach)
            & (pixels[:, 0] < intrinsics.width + reach)
            & (pixels[:, 1] > -reach)
            & (pixels[:, 1] < intrinsics.height + reach)
        )
        # np.rint rounds half to even as round() does; integer lists keep the loop to cv2 calls.
        centers = np.rint(pixels[near]).astype(np.int64).tolist()
        radii = np.rint(radius_px[near]).astype(np.int64).tolist()
        for (u, v), r in zip(centers, radii, strict=True):
            cv2.circle(silhouette, (u, v), r, 1, thickness=-1)
        return silhouette.astype(bool)


def _secondary_pixel_counts(labels: np.ndarray, n_secondaries: int) -> np.ndarray:
    """(G,) pixels of each secondary label among ``labels`` (any shape)."""
    # Only the secondaries' own labels: the orchard's row and background labels lie above them,
    # and counting those too made this ~8x slower there.
    offset = labels.reshape(-1) - FIRST_SECONDARY_LABEL
    secondary = offset[(offset >= 0) & (offset < n_secondaries)]
    return np.bincount(secondary, minlength=n_secondaries)


def branch_rows(
    truth: TreeGT,
    metrics: TreeMetrics,
    visibility: BranchVisibility,
    config: AttributionConfig | None = None,
) -> list[dict[str, object]]:
    """One row per ground-truth secondary: geometry, visibility, match, completeness, miss kind.

    Columns: ``branch`` (index in ``truth.secondaries``), ``axis_angle_deg`` (angle between the
    branch's horizontal base-to-tip direction and the home optical axis (world +y) line, 0 =
    pointing straight toward or away from the camera, 90 = across the view), ``elevation_deg``,
    ``length_m``, ``base_height_m``, ``peak_visible_px``, ``peak_view_angle_deg``, ``in_scope``,
    ``matched``, ``completeness`` (NaN unless matched), ``residual_mm`` (NaN unless matched),
    ``miss`` ("" for a matched or out-of-scope branch, else ``seen`` or ``never_seen``).
    """
    config = config or AttributionConfig()
    completeness = {
        j: c for (j, _), c in zip(metrics.matches, metrics.match_completeness, strict=True)
    }
    residual = {j: r for (j, _), r in zip(metrics.matches, metrics.match_residual_m, strict=True)}
    rows = []
    for j, branch in enumerate(truth.secondaries):
        points = np.asarray(branch.points, float)
        direction = points[-1] - points[0]
        horizontal = float(np.linalg.norm(direction[:2]))
        # The home optical axis is world +y: the angle to its line is atan2(|dx|, |dy|).
        axis_angle = math.atan2(abs(float(direction[0])), abs(float(direction[1])))
        in_scope = bool(metrics.gt_in_scope[j]) if j < len(metrics.gt_in_scope) else False
        matched = j in completeness
        peak = int(visibility.peak_pixels[j]) if j < len(visibility.peak_pixels) else 0
        miss = ""
        if in_scope and not matched:
            miss = MISS_SEEN if peak >= config.seen_min_pixels else MISS_NEVER_SEEN
        rows.append(
            {
                "branch": j,
                "axis_angle_deg": math.degrees(axis_angle),
                "elevation_deg": math.degrees(math.atan2(direction[2], horizontal)),
                "length_m": float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))),
                "base_height_m": float(points[0, 2]),
                "peak_visible_px": peak,
                "peak_view_angle_deg": float(visibility.peak_view_angle_deg[j])
                if j < len(visibility.peak_view_angle_deg)
                else math.nan,
                "in_scope": in_scope,
                "matched": matched,
                "completeness": float(completeness.get(j, math.nan)),
                "residual_mm": float(residual.get(j, math.nan)) * _MM_PER_M,
                "miss": miss,
            }
        )  # fmt: skip
    return rows


def miss_counts(branches: list[dict[str, object]]) -> dict[str, int]:
    """``n_missed_seen`` and ``n_missed_never_seen`` of a scan's branch rows."""
    return {
        "n_missed_seen": sum(row["miss"] == MISS_SEEN for row in branches),
        "n_missed_never_seen": sum(row["miss"] == MISS_NEVER_SEEN for row in branches),
    }
