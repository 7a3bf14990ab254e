"""A recording at the pipeline's working resolution: frames, masks and flow pictures resized.

The pipeline sees branches in pixels. The paper's thresholds (the 2D stage's 10 px image
border and 20 px side branches, the 4 px inlier and consistency tolerances, LK's 11 px window:
``docs/replay.md``) were set for the authors' simulated camera, 320x240 px with a 416.8 px focal
length (:data:`PIPELINE_FOCAL_PX`), and the shipped segmenter was trained on renders of that
camera only. A camera with twice the focal length in pixels (a 640x480 camera of the same field
of view) shows every branch twice as wide: on the real development frames at their own 640x480
the shipped segmenter reads 0.54 pooled IoU, at 320x240 0.65 (``docs/replay.md``).

:class:`RescaledSource` wraps any :class:`recon.io.ScanSource` and resizes its undistorted
frames so that their focal length becomes ``focal_px`` (``python -m recon.replay
--working-focal-px``; by default :data:`PIPELINE_FOCAL_PX` with ``--segmenter learned``):
images and flow pictures by area when shrinking (bilinear when growing), masks by area and
thresholded at half (:func:`resize_mask`), the intrinsics scaled with them (pixel centres
kept: ``c' = (c + 0.5) * s - 0.5``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from recon.camera import CameraIntrinsics
from recon.io.folder import LoadedFrame
from recon.io.source import ScanSource

PIPELINE_FOCAL_PX = CameraIntrinsics.from_fov().fx
"""Focal length (px) of the camera the pipeline's pixel thresholds and the shipped segmenter
were made for: the authors' simulated camera, 320x240 px, 42 deg horizontal FoV (~416.8 px)."""

MASK_AREA_THRESHOLD = 0.5
"""A resized mask pixel is on when at least half of the source area it covers is (INTER_AREA
averages the source pixels; 0.5 keeps a 1 px line of a 640 px wide mask at 320 px)."""


def resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W) mask resized to ``size`` = (W', H') by area, on where half of it is.

    Args:
        mask: (H, W) bool or {0, 1} mask.
        size: (width, height) in pixels.

    Returns:
        (H', W') bool mask.
    """
    area = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    return area >= MASK_AREA_THRESHOLD


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, C) image resized to ``size`` = (W', H'): by area when shrinking, else bilinear."""
    shrinking = size[0] < image.shape[1]
    interpolation = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    return cv2.resize(image, size, interpolation=interpolation)


def scaled_intrinsics(intrinsics: CameraIntrinsics, size: tuple[int, int]) -> CameraIntrinsics:
    """The intrinsics of the frames resized to ``size`` = (W', H') (pixel centres kept)."""
    sx, sy = size[0] / intrinsics.width, size[1] / intrinsics.height
    return CameraIntrinsics(
        width=size[0],
        height=size[1],
        fx=intrinsics.fx * sx,
        fy=intrinsics.fy * sy,
        cx=(intrinsics.cx + 0.5) * sx - 0.5,
        cy=(intrinsics.cy + 0.5) * sy - 0.5,
    )


def working_size(intrinsics: CameraIntrinsics, focal_px: float) -> tuple[int, int]:
    """(W', H') of the frames whose focal length (the mean of fx and fy) becomes ``focal_px``.

    Raises:
        ValueError: ``focal_px`` is not a positive finite number, or the size would be under
            one pixel.
    """
    if not (math.isfinite(focal_px) and focal_px > 0.0):
        raise ValueError(
            f"working focal length must be a positive number of pixels, got {focal_px}"
        )
    scale = focal_px / (0.5 * (intrinsics.fx + intrinsics.fy))
    size = (round(intrinsics.width * scale), round(intrinsics.height * scale))
    if min(size) < 1:
        raise ValueError(
            f"a working focal length of {focal_px} px shrinks the {intrinsics.width}x"
            f"{intrinsics.height} px frames (fx {intrinsics.fx:.1f} px) below one pixel"
        )
    return size


class RescaledSource:
    """A :class:`recon.io.ScanSource` whose frames are resized to a working focal length.

    Args:
        source: The recording.
        focal_px: The focal length in pixels the frames are resized to
            (:data:`PIPELINE_FOCAL_PX` for the pipeline's own camera).
    """

    def __init__(self, source: ScanSource, focal_px: float) -> None:
        self.source = source
        self.name = source.name
        self.metadata = source.metadata
        self.size = working_size(source.intrinsics, focal_px)
        self._intrinsics = scaled_intrinsics(source.intrinsics, self.size)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def has_masks(self) -> bool:
        return self.source.has_masks

    @property
    def frames_without_mask(self) -> list[int]:
        return self.source.frames_without_mask

    def __len__(self) -> int:
        return len(self.source)

    def truth_path(self) -> Path | None:
        return self.source.truth_path()

    def frames(self, load_masks: bool = True, load_flow: bool = False) -> Iterator[LoadedFrame]:
        """The source's frames, their image, mask and flow picture resized."""
        for loaded in self.source.frames(load_masks=load_masks, load_flow=load_flow):
            if loaded.rgb is None:  # pose only, or skipped
                yield loaded
                continue
            yield replace(
                loaded,
                rgb=resize_image(loaded.rgb, self.size),
                mask=None if loaded.mask is None else resize_mask(loaded.mask, self.size),
                flow_image=None
                if loaded.flow_image is None
                else resize_image(loaded.flow_image, self.size),
            )
