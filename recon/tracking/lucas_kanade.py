"""OpenCV pyramidal Lucas-Kanade point tracking with a forward-backward check (paper IV-C).

:class:`LucasKanadeTracker` chains LK from the newest frame of the tracking window to the oldest;
RGB only, what a real robot runs.
"""

from __future__ import annotations

import logging
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from recon.frame import Frame
from recon.tracking.tracks import Tracks, check_window
from recon.validation import require_non_negative, require_positive

logger = logging.getLogger(__name__)

# Grey images kept per tracker: two tracking windows of M = 8 (paper IV-C) with room to spare.
_GRAY_CACHE_SIZE = 32


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
        require_positive(self, "forward_backward_threshold_px", finite=False)
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        require_positive(self, "epsilon_px", finite=False)
        require_non_negative(self, "min_eigen_threshold", "border_margin_px", finite=False)
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
        frames, query = check_window(frames, query_px)
        for i, frame in enumerate(frames):
            if not frame.has_image:
                raise ValueError(
                    f"frame {i} is pose-only (no image): the Lucas-Kanade tracker needs images"
                )
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
