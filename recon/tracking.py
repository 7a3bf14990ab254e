"""Point tracking over the tracking window (paper section IV-C).

The modeler asks a :class:`PointTracker` where the pixels it queried in the newest frame appear in
the M frames of the tracking window. Three implementations:

* :class:`LucasKanadeTracker`: OpenCV pyramidal Lucas-Kanade, chained from the newest frame to the
  oldest with a forward-backward check per step. RGB only, what a real robot runs.
* :class:`LearnedTrackerAdapter`: wraps a learned tracker (PIPs-class: M RGB images in, tracks and
  visibility out) behind the same interface.
* :class:`DepthOracleTracker`: exact tracks from the depth the frames carry (renderer or RGB-D),
  for ablations and fast training.
"""

from __future__ import annotations

import logging
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from recon.camera import project_points, unproject_pixels
from recon.frame import Frame

logger = logging.getLogger(__name__)

# A learned tracker: (M, H, W, 3) uint8 images and (N, 2) query pixels -> (M, N, 2) tracks and
# (M, N) visibility.
LearnedTrackFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

# Grey images kept per tracker: two tracking windows of M = 8 (paper IV-C) with room to spare.
_GRAY_CACHE_SIZE = 32


@dataclass
class Tracks:
    """Where the queried pixels appear in each frame of the tracking window.

    Attributes:
        pixels: (M, N, 2) pixel coordinates (u, v), frames oldest to newest; NaN where not valid
            (enforced: invalid entries are overwritten with NaN).
        valid: (M, N) boolean, True where the track is reliable in that frame.
    """

    pixels: np.ndarray
    valid: np.ndarray

    def __post_init__(self) -> None:
        pixels = np.array(self.pixels, dtype=float)
        valid = np.asarray(self.valid)
        if pixels.ndim != 3 or pixels.shape[2] != 2:
            raise ValueError(f"pixels must have shape (M, N, 2), got {pixels.shape}")
        if valid.shape != pixels.shape[:2]:
            raise ValueError(f"valid must have shape {pixels.shape[:2]}, got {valid.shape}")
        if valid.dtype != bool:
            raise ValueError(f"valid must be boolean, got dtype {valid.dtype}")
        if not np.all(np.isfinite(pixels[valid])):
            raise ValueError("pixels must be finite wherever valid is True")
        pixels[~valid] = np.nan
        self.pixels, self.valid = pixels, valid


class PointTracker(Protocol):
    """Anything that tracks query pixels of the newest frame through the tracking window."""

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Track the queries.

        Args:
            frames: The M tracking frames, oldest first; the queries live in ``frames[-1]``.
            query_px: (N, 2) pixels (u, v) in the newest frame.

        Returns:
            Tracks with ``pixels`` (M, N, 2) and ``valid`` (M, N).
        """
        ...


@dataclass(frozen=True)
class LucasKanadeConfig:
    """Parameters of :class:`LucasKanadeTracker`.

    Attributes:
        window_size_px: Side of the square LK window; odd. 11 px (reference.md, "Tracking on
            rendered images": it must stay below the branch's image width; 21 px biased depth).
        max_pyramid_level: Pyramid levels above the full image. 1 (reference.md, same section:
            image motion is 2-4 px per frame).
        forward_backward_threshold_px: A step passes when tracking back lands within this of where
            it started. 0.5 px (reference.md, same section).
        max_iterations: LK iterations per pyramid level (OpenCV's default, 30).
        epsilon_px: LK stops when an update is smaller than this (OpenCV's default, 0.01 px).
        min_eigen_threshold: Minimum eigenvalue of the window's normalised gradient matrix: below it
            the window is texture-free and the track fails (OpenCV's default, 1e-4).
        border_margin_px: Tracks closer than this to the image border are invalid (our choice:
            half the window, so the window never reaches past the border, where LK errs by 0.1-0.3
            px on unseen content; the 2D stage already drops pixels within 10 px, reference.md).
        crop_margin_px: LK runs on the points' bounding box grown by this margin rather than on the
            whole image (for speed: LK's cost follows the image area). It must exceed the window
            plus the largest frame-to-frame image motion, which maxLevel 1 limits to ~20 px (our
            choice: 40 px; reference.md measured 2-4 px per frame). None: whole image.
    """

    window_size_px: int = 11
    max_pyramid_level: int = 1
    forward_backward_threshold_px: float = 0.5
    max_iterations: int = 30
    epsilon_px: float = 0.01
    min_eigen_threshold: float = 1e-4
    border_margin_px: float = 5.0
    crop_margin_px: int | None = 40

    def __post_init__(self) -> None:
        if self.window_size_px < 3 or self.window_size_px % 2 == 0:
            raise ValueError(f"window_size_px must be odd and >= 3, got {self.window_size_px}")
        if self.max_pyramid_level < 0:
            raise ValueError(f"max_pyramid_level must be >= 0, got {self.max_pyramid_level}")
        if not self.forward_backward_threshold_px > 0.0:
            raise ValueError(
                "forward_backward_threshold_px must be positive, "
                f"got {self.forward_backward_threshold_px}"
            )
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if not self.epsilon_px > 0.0:
            raise ValueError(f"epsilon_px must be positive, got {self.epsilon_px}")
        if not self.min_eigen_threshold >= 0.0:
            raise ValueError(f"min_eigen_threshold must be >= 0, got {self.min_eigen_threshold}")
        if not self.border_margin_px >= 0.0:
            raise ValueError(f"border_margin_px must be >= 0, got {self.border_margin_px}")
        if self.crop_margin_px is not None and self.crop_margin_px < self.window_size_px:
            raise ValueError(
                f"crop_margin_px must be None or >= window_size_px, got {self.crop_margin_px}"
            )


class LucasKanadeTracker:
    """Pyramidal Lucas-Kanade, newest frame to oldest, one frame pair at a time.

    Each step tracks the still-valid points from frame k+1 into frame k, tracks them back, and keeps
    those that return within the forward-backward threshold and stay inside the image by the border
    margin (queries outside it are invalid from the start). A track that fails once stays invalid
    for all older frames. Grey images are cached per frame object (frames are treated as
    immutable), so tracking the same window again (primary, then secondaries) converts them once.
    """

    def __init__(self, config: LucasKanadeConfig | None = None) -> None:
        self.config = config or LucasKanadeConfig()
        self._gray_cache: dict[int, tuple[weakref.ref[Frame], np.ndarray]] = {}

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Track ``query_px`` of ``frames[-1]`` back to ``frames[0]``; see :class:`PointTracker`."""
        frames, query = _check_window(frames, query_px)
        pixels = np.full((len(frames), len(query), 2), np.nan)
        active = frames[-1].intrinsics.in_image(query, self.config.border_margin_px)
        pixels[-1, active] = query[active]
        newer_gray = self._gray(frames[-1])
        for k in range(len(frames) - 2, -1, -1):
            index = np.flatnonzero(active)
            if index.size == 0:
                break
            older_gray = self._gray(frames[k])
            moved, ok = self._step(newer_gray, older_gray, pixels[k + 1, index], frames[k])
            active[index[~ok]] = False
            pixels[k, index[ok]] = moved[ok]
            newer_gray = older_gray
        logger.debug("LK: %d of %d tracks reach the oldest frame", active.sum(), len(query))
        return Tracks(pixels, np.isfinite(pixels[..., 0]))

    def _step(
        self, newer: np.ndarray, older: np.ndarray, start_px: np.ndarray, older_frame: Frame
    ) -> tuple[np.ndarray, np.ndarray]:
        """Track (K, 2) pixels from ``newer`` into ``older`` with a forward-backward check.

        Returns:
            (K, 2) pixels in the older image and (K,) boolean success.
        """
        cfg = self.config
        lk_args = {
            "winSize": (cfg.window_size_px, cfg.window_size_px),
            "maxLevel": cfg.max_pyramid_level,
            "criteria": (
                cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                cfg.max_iterations,
                cfg.epsilon_px,
            ),
            "minEigThreshold": cfg.min_eigen_threshold,
        }
        (u0, v0), (u1, v1) = self._crop_box(start_px, newer.shape)
        newer, older = newer[v0:v1, u0:u1], older[v0:v1, u0:u1]
        offset = np.array([u0, v0], dtype=float)
        start = (start_px - offset).astype(np.float32).reshape(-1, 1, 2)
        moved, status_forward, _ = cv2.calcOpticalFlowPyrLK(newer, older, start, None, **lk_args)
        back, status_backward, _ = cv2.calcOpticalFlowPyrLK(older, newer, moved, None, **lk_args)
        round_trip_px = np.linalg.norm(back.reshape(-1, 2) - start.reshape(-1, 2), axis=1)
        moved = moved.reshape(-1, 2).astype(float) + offset
        with np.errstate(invalid="ignore"):
            ok = (
                (status_forward.ravel() == 1)
                & (status_backward.ravel() == 1)
                & (round_trip_px < cfg.forward_backward_threshold_px)
                & older_frame.intrinsics.in_image(moved, cfg.border_margin_px)
            )
        return moved, ok

    def _crop_box(
        self, pixels: np.ndarray, shape: tuple[int, ...]
    ) -> tuple[tuple[int, int], tuple[int, int]]:
        """((u0, v0), (u1, v1)) image region holding (K, 2) pixels with the crop margin.

        The corner is aligned to the coarsest pyramid level, so the crop's pyramid samples the same
        pixels as the whole image's.
        """
        height, width = shape[:2]
        if self.config.crop_margin_px is None:
            return (0, 0), (width, height)
        align = 2**self.config.max_pyramid_level
        margin = self.config.crop_margin_px
        low = np.floor(pixels.min(axis=0) - margin).astype(int) // align * align
        high = np.ceil(pixels.max(axis=0) + margin).astype(int)
        u0, v0 = np.maximum(low, 0)
        u1, v1 = np.minimum(high, (width, height))
        return (int(u0), int(v0)), (int(u1), int(v1))

    def _gray(self, frame: Frame) -> np.ndarray:
        """(H, W) uint8 grey image of a frame, cached by frame identity.

        ``cv2.cvtColor`` uses the ITU-R 601 weights of :attr:`recon.frame.Frame.gray` (in fixed
        point: at most one grey level apart) at a fortieth of the cost.
        """
        key = id(frame)
        cached = self._gray_cache.get(key)
        if cached is not None and cached[0]() is frame:
            return cached[1]
        gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        if len(self._gray_cache) >= _GRAY_CACHE_SIZE:
            del self._gray_cache[next(iter(self._gray_cache))]  # oldest entry
        # The weak reference tells a live frame from a dead one that left its id behind.
        self._gray_cache[key] = (weakref.ref(frame), gray)
        return gray


class LearnedTrackerAdapter:
    """Puts a learned tracker (PIPs-class) behind the :class:`PointTracker` interface.

    Args:
        track_fn: ``(images (M, H, W, 3) uint8, query_px (N, 2)) -> (tracks (M, N, 2), visible
            (M, N))``. By default the images are ordered oldest to newest and the queries live in
            the last image.
        queries_in_first_image: Set for models that query the first image (PIPs does): the images
            are then passed newest first and the outputs flipped back.
    """

    def __init__(self, track_fn: LearnedTrackFn, queries_in_first_image: bool = False) -> None:
        self.track_fn = track_fn
        self.queries_in_first_image = queries_in_first_image

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Run the learned tracker; see :class:`PointTracker`.

        Tracks outside the image or not finite are marked invalid.

        Raises:
            ValueError: the model's outputs have the wrong shape.
        """
        frames, query = _check_window(frames, query_px)
        images = np.stack([frame.rgb for frame in frames])
        if self.queries_in_first_image:
            images = images[::-1]
        tracks, visible = self.track_fn(images, query.copy())
        tracks = np.asarray(tracks, dtype=float)
        visible = np.asarray(visible)
        expected = (len(frames), len(query))
        if tracks.shape != (*expected, 2):
            raise ValueError(
                f"learned tracker returned tracks {tracks.shape}, expected {(*expected, 2)}"
            )
        if visible.shape != expected:
            raise ValueError(
                f"learned tracker returned visible {visible.shape}, expected {expected}"
            )
        if self.queries_in_first_image:
            tracks, visible = tracks[::-1], visible[::-1]
        in_image = np.stack([f.intrinsics.in_image(t) for f, t in zip(frames, tracks, strict=True)])
        valid = visible.astype(bool) & np.all(np.isfinite(tracks), axis=2) & in_image
        return Tracks(np.where(valid[..., None], tracks, np.nan), valid)


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
        if not self.occlusion_tolerance_m > 0.0:
            raise ValueError(
                f"occlusion_tolerance_m must be positive, got {self.occlusion_tolerance_m}"
            )


class DepthOracleTracker:
    """Exact tracks from per-frame depth (the simulator's renderer or an RGB-D camera).

    The queries are unprojected with the newest frame's depth and pose and projected into every
    older frame; a track is invalid where it falls outside the image, behind the camera, on a pixel
    without depth (non-positive or NaN), or behind the surface that frame sees (occluded).
    """

    def __init__(self, config: DepthOracleConfig | None = None) -> None:
        self.config = config or DepthOracleConfig()

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Track by geometry; see :class:`PointTracker`.

        Raises:
            ValueError: a frame carries no depth map.
        """
        frames, query = _check_window(frames, query_px)
        for i, frame in enumerate(frames):
            if frame.depth_m is None:
                raise ValueError(f"frame {i} has no depth_m: the depth oracle tracker needs depth")
        tolerance = self.config.occlusion_tolerance_m
        newest = frames[-1]
        pixels = np.full((len(frames), len(query), 2), np.nan)
        seen = newest.intrinsics.in_image(query)
        depth = np.full(len(query), np.nan)
        depth[seen] = _sample_depth(newest.depth_m, query[seen], tolerance)
        seen &= depth > 0.0  # NaN compares False
        pixels[-1, seen] = query[seen]
        points = unproject_pixels(
            query[seen], depth[seen], newest.T_world_camera, newest.intrinsics
        )
        index = np.flatnonzero(seen)
        for k, frame in enumerate(frames[:-1]):
            projected, z_m = project_points(points, frame.T_world_camera, frame.intrinsics)
            inside = frame.intrinsics.in_image(projected) & (z_m > 0.0)
            surface = _sample_depth(frame.depth_m, projected[inside], tolerance)
            with np.errstate(invalid="ignore"):
                visible = (surface > 0.0) & (z_m[inside] <= surface + tolerance)
            keep = np.flatnonzero(inside)[visible]
            pixels[k, index[keep]] = projected[keep]
        return Tracks(pixels, np.isfinite(pixels[..., 0]))


def _check_window(frames: Sequence[Frame], query_px: np.ndarray) -> tuple[list[Frame], np.ndarray]:
    """Validate a tracking window and its queries; return a list of frames and (N, 2) floats."""
    frames = list(frames)
    if not frames:
        raise ValueError("frames is empty: a tracking window needs at least one frame")
    query = np.asarray(query_px, dtype=float)
    if query.ndim != 2 or query.shape[1] != 2:
        raise ValueError(f"query_px must have shape (N, 2), got {query.shape}")
    if not np.all(np.isfinite(query)):
        raise ValueError("query_px contains NaN or infinite values")
    size = (frames[-1].intrinsics.width, frames[-1].intrinsics.height)
    for i, frame in enumerate(frames):
        if (frame.intrinsics.width, frame.intrinsics.height) != size:
            raise ValueError(f"frame {i} image size differs from the newest frame's {size}")
    return frames, query


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
