"""Exact point tracks from the depth the frames carry (renderer or RGB-D), for ablations and fast
training: :class:`DepthOracleTracker` unprojects the queries once and projects them into every
older frame, with an occlusion test against each frame's depth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recon.camera import project_points, unproject_pixels
from recon.frame import Frame
from recon.tracking.tracks import Tracks, check_window
from recon.validation import require_positive


@dataclass(frozen=True)
class DepthOracleConfig:
    """Parameters of :class:`DepthOracleTracker`.

    Attributes:
        occlusion_tolerance_m: A projected point is occluded when it lies deeper than the frame's
            depth at its pixel by more than this (our choice: 2 mm, well below the 6-15 mm branch
            diameters of reference.md and above rendering depth noise).
    """

    occlusion_tolerance_m: float = 0.002

    def __post_init__(self) -> None:
        require_positive(self, "occlusion_tolerance_m", finite=False)


class DepthOracleTracker:
    """Exact tracks from per-frame depth (the simulator's renderer or an RGB-D camera).

    The queries are unprojected with the newest frame's depth and pose and projected into every
    older frame; a track is invalid where it falls outside the image, behind the camera, on a pixel
    without depth (non-positive or NaN), or behind the surface that frame sees (occluded).
    Older pose-only frames (:meth:`recon.frame.Frame.pose_only`, no depth) get the projection
    without the occlusion test: the window spans ~7 mm of motion, over which what hides a point
    from the newest frame hides it from the older ones too.
    """

    def __init__(self, config: DepthOracleConfig | None = None) -> None:
        self.config = config or DepthOracleConfig()

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Track by geometry; see :class:`PointTracker`.

        Raises:
            ValueError: the newest frame, or an older frame that is not pose-only, carries no
                depth map.
        """
        frames, query = check_window(frames, query_px)
        for i, frame in enumerate(frames):
            if frame.depth_m is None and (frame.has_image or i == len(frames) - 1):
                raise ValueError(f"frame {i} has no depth_m: the depth oracle tracker needs depth")
        tolerance = self.config.occlusion_tolerance_m
        newest = frames[-1]
        pixels = np.full((len(frames), len(query), 2), np.nan)
        seen = newest.intrinsics.in_image(query)
        depth = np.full(len(query), np.nan)
        depth[seen] = _sample_depth(newest.depth_m, query[seen], tolerance)
        seen &= np.isfinite(depth) & (depth > 0.0)  # not NaN (unknown) nor inf (the sky)
        pixels[-1, seen] = query[seen]
        points = unproject_pixels(
            query[seen], depth[seen], newest.T_world_camera, newest.intrinsics
        )
        index = np.flatnonzero(seen)
        for k, frame in enumerate(frames[:-1]):
            projected, z_m = project_points(points, frame.T_world_camera, frame.intrinsics)
            inside = frame.intrinsics.in_image(projected) & (z_m > 0.0)
            if frame.depth_m is None:  # pose-only: no occlusion test
                keep = np.flatnonzero(inside)
                pixels[k, index[keep]] = projected[keep]
                continue
            surface = _sample_depth(frame.depth_m, projected[inside], tolerance)
            with np.errstate(invalid="ignore"):
                visible = (surface > 0.0) & (z_m[inside] <= surface + tolerance)
            keep = np.flatnonzero(inside)[visible]
            pixels[k, index[keep]] = projected[keep]
        return Tracks(pixels, np.isfinite(pixels[..., 0]))


def _sample_depth(depth_m: np.ndarray, pixels: np.ndarray, tolerance_m: float) -> np.ndarray:
    """Depth at sub-pixel positions.

    Bilinear in inverse depth (exact for planes) where the four neighbouring pixels agree within
    ``tolerance_m``; the nearest pixel's depth across depth edges, so that foreground and background
    are never blended into a point in mid-air.

    Args:
        depth_m: (H, W) depth map in metres; pixel centres at integer coordinates.
        pixels: (K, 2) pixels (u, v) inside the image.
        tolerance_m: Largest spread of the four neighbours for interpolation.

    Returns:
        (K,) depth in metres (NaN or non-positive where the map has no depth).
    """
    depth_m = np.asarray(depth_m, dtype=float)
    height, width = depth_m.shape
    u = np.clip(pixels[:, 0], 0.0, width - 1.0)
    v = np.clip(pixels[:, 1], 0.0, height - 1.0)
    u0 = np.clip(np.floor(u).astype(int), 0, max(width - 2, 0))
    v0 = np.clip(np.floor(v).astype(int), 0, max(height - 2, 0))
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    fu, fv = u - u0, v - v0
    corners = np.stack([depth_m[v0, u0], depth_m[v0, u1], depth_m[v1, u0], depth_m[v1, u1]], axis=1)
    weights = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
    nearest = depth_m[np.rint(v).astype(int), np.rint(u).astype(int)]
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = np.all(np.isfinite(corners) & (corners > 0.0), axis=1) & (
            corners.max(axis=1) - corners.min(axis=1) <= tolerance_m
        )
        interpolated = 1.0 / np.sum(weights / corners, axis=1)
    return np.where(smooth, interpolated, nearest)
