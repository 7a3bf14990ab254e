"""Lifting 2D branch samples to 3D centre points (paper IV-C and the lifting paragraph of IV).

Track the sampled pixels of the newest frame back through the tracking window, triangulate them
(paper eq. 1), drop implausible points (depth above 1 m, reprojection error above 4 px), and move
each surviving surface point to the branch axis by its 3D radius along the viewing ray.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from recon.camera import invert_pose, projection_matrix, transform_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.geometry.triangulate import triangulate_points
from recon.timing import stage_timer
from recon.tracking import PointTracker


@dataclass
class LiftedPoints:
    """3D estimates of queried pixels; only the points that passed every filter.

    Attributes:
        index: (K,) indices into the queried pixels of the kept points.
        centers: (K, 3) branch-axis points in metres, world frame.
        radii_m: (K,) branch radius in metres at each point.
        depth_m: (K,) camera-frame depth of the surface points in the newest frame.
        reprojection_px: (K,) maximum reprojection error of each kept point.
        timings_ms: Milliseconds spent tracking and triangulating.
    """

    index: np.ndarray
    centers: np.ndarray
    radii_m: np.ndarray
    depth_m: np.ndarray
    reprojection_px: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)

    @classmethod
    def empty(cls) -> LiftedPoints:
        return cls(np.zeros(0, int), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.index)


def radius_from_pixels(
    radius_px: np.ndarray, depth_m: np.ndarray, focal_px: float, paper_formula: bool
) -> np.ndarray:
    """3D radius (m) of a branch of half-width ``radius_px`` seen at surface depth ``depth_m``.

    The paper uses ``r = z r_px / f``. The surface point seen at the silhouette centre lies ``r``
    nearer than the axis, so the axis depth is ``z + r``; solving ``r_px = f r / (z + r)`` gives
    ``r = z r_px / (f - r_px)``, the default.
    """
    if paper_formula:
        return depth_m * radius_px / focal_px
    return depth_m * radius_px / np.maximum(focal_px - radius_px, 1e-9)


def lift_pixels(
    frames: Sequence[Frame],
    query_px: np.ndarray,
    radii_px: np.ndarray,
    tracker: PointTracker,
    config: ModelerConfig,
) -> LiftedPoints:
    """Track, triangulate, filter and centre the queried pixels of the newest frame.

    Args:
        frames: The tracking window, oldest first; queries are in ``frames[-1]``.
        query_px: (N, 2) pixels (u, v) in the newest frame, on the branch's 2D centerline.
        radii_px: (N,) silhouette half-width in pixels at each query.
        tracker: Any :class:`recon.tracking.PointTracker`.
        config: Depth and reprojection limits and the radius formula.

    Returns:
        The points that survived, with their indices into ``query_px``.
    """
    query_px = np.asarray(query_px, dtype=float).reshape(-1, 2)
    radii_px = np.asarray(radii_px, dtype=float).reshape(-1)
    if len(query_px) != len(radii_px):
        raise ValueError(f"{len(query_px)} query pixels but {len(radii_px)} radii")
    if len(query_px) == 0:
        return LiftedPoints.empty()
    timings: dict[str, float] = {}
    with stage_timer(timings, "tracking_ms"):
        tracks = tracker.track(frames, query_px)
    with stage_timer(timings, "triangulation_ms"):
        projections = np.stack([projection_matrix(f.intrinsics, f.T_world_camera) for f in frames])
        surface, reprojection = triangulate_points(tracks.pixels, projections)

    newest = frames[-1]
    depth = transform_points(invert_pose(newest.T_world_camera), np.nan_to_num(surface))[:, 2]
    ok = (
        np.all(np.isfinite(surface), axis=1)
        & (reprojection <= config.max_reprojection_px)
        & (depth > 0.0)
        & (depth <= config.max_depth_m)
    )
    index = np.flatnonzero(ok)
    radii_m = radius_from_pixels(
        radii_px[index], depth[index], newest.intrinsics.fx, config.radius_from_paper_formula
    )
    camera_center = newest.T_world_camera[:3, 3]
    rays = surface[index] - camera_center
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    centers = surface[index] + rays * radii_m[:, None]
    return LiftedPoints(index, centers, radii_m, depth[index], reprojection[index], timings)
