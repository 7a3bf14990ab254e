"""The pipeline's input: one camera frame with its mask and pose."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from recon.camera import CameraIntrinsics, check_pose


@dataclass
class Frame:
    """One observation: what a real robot or the simulator hands to the modeler.

    Attributes:
        rgb: (H, W, 3) uint8 colour image.
        mask: (H, W) boolean branch mask (True = branch). Integer/float masks holding only 0 and 1
            are accepted and converted; anything else is rejected.
        T_world_camera: (4, 4) camera pose, camera frame (OpenCV axes) to world frame.
        intrinsics: Camera intrinsics matching the image size.
        timestamp_s: Optional acquisition time in seconds.
        depth_m: Optional (H, W) metric depth; only oracle trackers and diagnostics may read it.
        has_image: False for a pose-only frame (:meth:`pose_only`): its ``rgb`` and ``mask`` are
            blank placeholders that image trackers must refuse.
    """

    rgb: np.ndarray
    mask: np.ndarray
    T_world_camera: np.ndarray
    intrinsics: CameraIntrinsics
    timestamp_s: float | None = None
    depth_m: np.ndarray | None = None
    has_image: bool = True

    @classmethod
    def pose_only(
        cls,
        T_world_camera: np.ndarray,
        intrinsics: CameraIntrinsics,
        timestamp_s: float | None = None,
    ) -> Frame:
        """A frame that carries only where the camera was (no image was rendered or captured).

        A depth oracle tracker can project points into such a frame, which lets a simulator
        render only the frames that a modeling iteration runs on (fast training).
        """
        blank_rgb, blank_mask = _blank_images(intrinsics.height, intrinsics.width)
        return cls(blank_rgb, blank_mask, T_world_camera, intrinsics, timestamp_s, None, False)

    def __post_init__(self) -> None:
        h, w = self.intrinsics.height, self.intrinsics.width
        rgb = np.asarray(self.rgb)
        if rgb.shape != (h, w, 3):
            raise ValueError(
                f"rgb must have shape ({h}, {w}, 3) to match intrinsics, got {rgb.shape}"
            )
        self.rgb = rgb.astype(np.uint8, copy=False)
        self.mask = as_binary_mask(self.mask, (h, w))
        self.T_world_camera = check_pose(self.T_world_camera)
        if self.depth_m is not None and np.shape(self.depth_m) != (h, w):
            raise ValueError(f"depth_m must have shape ({h}, {w}), got {np.shape(self.depth_m)}")

    @property
    def gray(self) -> np.ndarray:
        """(H, W) uint8 luminance image (ITU-R 601 weights)."""
        rgb = self.rgb.astype(np.float32)
        gray = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
        return np.clip(gray + 0.5, 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=4)
def _blank_images(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only black (H, W, 3) image and empty (H, W) mask, shared by every pose-only frame."""
    rgb, mask = np.zeros((height, width, 3), np.uint8), np.zeros((height, width), bool)
    rgb.flags.writeable = mask.flags.writeable = False
    return rgb, mask


def as_binary_mask(mask: np.ndarray, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Validate a branch mask and return it as a boolean array.

    Raises:
        ValueError: wrong shape, or values other than {0, 1} / {False, True}.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D (H, W), got shape {mask.shape}")
    if shape is not None and mask.shape != tuple(shape):
        raise ValueError(f"mask must have shape {tuple(shape)}, got {mask.shape}")
    if mask.dtype == bool:
        return mask
    if not np.issubdtype(mask.dtype, np.number):
        raise ValueError(f"mask must be numeric or boolean, got dtype {mask.dtype}")
    if not np.all(np.isin(mask, (0, 1))):
        raise ValueError("mask is not binary: it holds values other than 0 and 1")
    return mask.astype(bool)
