"""Synthetic scenes for recon tests, without any renderer: tubes, cameras, masks and exact tracks.

A tree is a list of tubes (polyline + radius per point). Masks are rasterised by drawing the
projected cross-section discs of each tube; tracks come from ray-casting the tubes analytically and
projecting the hit points into the older frames, so they are exact up to the mask's rasterisation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from recon.camera import CameraIntrinsics, make_pose, project_points
from recon.frame import Frame
from recon.model import BranchModel, TreeModel
from recon.tracking import Tracks

# Camera looking along world +y with image up = world +z (OpenCV axes as columns).
R_WORLD_CAMERA_FORWARD_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass
class Tube:
    """(N, 3) centerline points in metres and (N,) radii."""

    points: np.ndarray
    radii: np.ndarray


def bezier_tube(control: np.ndarray, radius_m: float, n: int = 1000) -> Tube:
    t = np.linspace(0.0, 1.0, n)[:, None]
    c = np.asarray(control, float)
    pts = (
        (1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t**2 * c[2] + t**3 * c[3]
    )
    return Tube(pts, np.full(n, radius_m))


def straight_tube(start: np.ndarray, end: np.ndarray, radius_m: float, n: int = 200) -> Tube:
    pts = np.linspace(np.asarray(start, float), np.asarray(end, float), n)
    return Tube(pts, np.full(n, radius_m))


def side_branch(
    primary: Tube,
    height_m: float,
    yaw_deg: float,
    length_m: float,
    radius_m: float,
    elevation_deg: float = 10.0,
) -> Tube:
    """A straight secondary leaving the primary axis at ``height_m``."""
    base = primary.points[np.argmin(np.abs(primary.points[:, 2] - height_m))]
    yaw, elev = np.radians(yaw_deg), np.radians(elevation_deg)
    direction = np.array([np.cos(yaw) * np.cos(elev), np.sin(yaw) * np.cos(elev), np.sin(elev)])
    return straight_tube(base, base + length_m * direction, radius_m)


def rasterise_mask(
    tubes: Sequence[Tube], T_world_camera: np.ndarray, intrinsics: CameraIntrinsics
) -> np.ndarray:
    """(H, W) bool silhouette of the tubes: a filled disc per projected centerline point."""
    mask = np.zeros((intrinsics.height, intrinsics.width), np.uint8)
    shift = 4  # sub-pixel precision bits for cv2.circle
    for tube in tubes:
        px, depth = project_points(tube.points, T_world_camera, intrinsics)
        ok = (depth > 1e-3) & np.all(np.isfinite(px), axis=1)
        radius_px = intrinsics.fx * tube.radii[ok] / np.sqrt(depth[ok] ** 2 - tube.radii[ok] ** 2)
        for (u, v), r in zip(px[ok], radius_px, strict=True):
            centre = (round(u * 2**shift), round(v * 2**shift))
            cv2.circle(mask, centre, round(r * 2**shift), 1, -1, cv2.LINE_8, shift)
    return mask.astype(bool)


def ray_cast(
    tubes: Sequence[Tube], camera_center: np.ndarray, directions: np.ndarray
) -> np.ndarray:
    """First hit (N, 3) of rays with the tubes' capsule segments, NaN where nothing is hit."""
    best = np.full(len(directions), np.inf)
    for tube in tubes:
        a, b = tube.points[:-1], tube.points[1:]
        r = 0.5 * (tube.radii[:-1] + tube.radii[1:])
        axis = b - a
        seg_len = np.linalg.norm(axis, axis=1)
        axis = axis / seg_len[:, None]
        # Ray o + s d against the infinite cylinder of each segment, then clip to the segment.
        o = camera_center[None, None, :] - a[None, :, :]  # (1, S, 3)
        d = directions[:, None, :]  # (N, 1, 3)
        dd = np.einsum("nsk,sk->ns", np.broadcast_to(d, (len(directions), len(a), 3)), axis)
        od = np.einsum("nsk,sk->ns", np.broadcast_to(o, (len(directions), len(a), 3)), axis)
        d_perp = d - dd[..., None] * axis[None]
        o_perp = o - od[..., None] * axis[None]
        qa = np.einsum("nsk,nsk->ns", d_perp, d_perp)
        qb = 2 * np.einsum("nsk,nsk->ns", d_perp, np.broadcast_to(o_perp, d_perp.shape))
        qc = (
            np.einsum(
                "nsk,nsk->ns",
                np.broadcast_to(o_perp, d_perp.shape),
                np.broadcast_to(o_perp, d_perp.shape),
            )
            - r[None] ** 2
        )
        disc = qb**2 - 4 * qa * qc
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (-qb - np.sqrt(disc)) / (2 * qa)
        along = od + s * dd
        hit = (disc >= 0) & (s > 0) & (along >= 0) & (along <= seg_len[None])
        s = np.where(hit, s, np.inf)
        best = np.minimum(best, s.min(axis=1))
    points = camera_center[None] + best[:, None] * directions
    points[~np.isfinite(best)] = np.nan
    return points


class AnalyticTracker:
    """Exact tracks: ray-cast each query in the newest frame, project the hit into older frames."""

    def __init__(
        self,
        tubes: Sequence[Tube],
        pixel_noise_px: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.tubes = tubes
        self.noise = pixel_noise_px
        self.rng = rng or np.random.default_rng(0)

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        newest = frames[-1]
        intr = newest.intrinsics
        rays_cam = np.stack(
            [
                (query_px[:, 0] - intr.cx) / intr.fx,
                (query_px[:, 1] - intr.cy) / intr.fy,
                np.ones(len(query_px)),
            ],
            axis=1,
        )
        rays = rays_cam @ newest.T_world_camera[:3, :3].T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        hits = ray_cast(self.tubes, newest.T_world_camera[:3, 3], rays)
        pixels = np.stack(
            [project_points(np.nan_to_num(hits), f.T_world_camera, f.intrinsics)[0] for f in frames]
        )
        pixels[:, ~np.all(np.isfinite(hits), axis=1)] = np.nan
        if self.noise > 0:
            pixels = pixels + self.rng.normal(0.0, self.noise, pixels.shape)
        valid = np.all(np.isfinite(pixels), axis=2)
        return Tracks(pixels=pixels, valid=valid)


def camera_following(primary: Tube, height_m: float, distance_m: float = 0.20) -> np.ndarray:
    """Camera pose ``distance_m`` in front (-y) of the primary at ``height_m``, looking at it."""
    axis_point = primary.points[np.argmin(np.abs(primary.points[:, 2] - height_m))]
    centre = np.array([axis_point[0], axis_point[1] - distance_m, height_m])
    return make_pose(R_WORLD_CAMERA_FORWARD_Y, centre)


def synthetic_frames(
    tubes: Sequence[Tube], poses: Sequence[np.ndarray], intrinsics: CameraIntrinsics
) -> list[Frame]:
    """Frames with a flat grey image (the analytic tracker does not look at it) and exact masks."""
    rgb = np.full((intrinsics.height, intrinsics.width, 3), 128, np.uint8)
    return [
        Frame(rgb, rasterise_mask(tubes, T, intrinsics), T, intrinsics, float(i))
        for i, T in enumerate(poses)
    ]


def tree_truth(primary: Tube, secondaries: Sequence[Tube]) -> TreeModel:
    return TreeModel(
        BranchModel(primary.points, primary.radii),
        [BranchModel(s.points, s.radii) for s in secondaries],
    )
