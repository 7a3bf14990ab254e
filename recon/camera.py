"""Pinhole camera model: intrinsics, poses, projection and unprojection.

Conventions (used everywhere in ``recon`` and ``branch_gym``):

* Camera frame is OpenCV's: x right, y down, z forward along the optical axis.
* Pixel coordinates are ``(u, v)`` = (column, row) with the centre of the top-left pixel at (0, 0).
* ``T_world_camera`` is a (4, 4) homogeneous transform that maps points from the camera frame to the
  world frame: ``p_world = T_world_camera @ p_camera``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.validation import require_finite

# Authors' simulated camera (reference.md, "Simulated world"): 320x240, 42 deg horizontal FoV.
DEFAULT_WIDTH_PX = 320
DEFAULT_HEIGHT_PX = 240
DEFAULT_HFOV_DEG = 42.0


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics without distortion.

    Attributes:
        width: Image width in pixels.
        height: Image height in pixels.
        fx: Focal length along u in pixels.
        fy: Focal length along v in pixels.
        cx: Principal point u in pixels.
        cy: Principal point v in pixels.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        require_finite(self, "fx", "fy", "cx", "cy")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fov(
        cls,
        width: int = DEFAULT_WIDTH_PX,
        height: int = DEFAULT_HEIGHT_PX,
        hfov_deg: float = DEFAULT_HFOV_DEG,
    ) -> CameraIntrinsics:
        """Square-pixel intrinsics from the horizontal field of view, principal point at the centre.

        The default reproduces the authors' camera: fx = fy ~ 416.8 px, cx = 160, cy = 120.
        """
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width=width, height=height, fx=f, fy=f, cx=width / 2.0, cy=height / 2.0)

    @classmethod
    def from_matrix(cls, K: np.ndarray, width: int, height: int) -> CameraIntrinsics:
        """Intrinsics from a (3, 3) calibration matrix ``K``."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise ValueError(f"K must have shape (3, 3), got {K.shape}")
        return cls(width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def vfov_rad(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * math.atan2(self.height / 2.0, self.fy)

    def vertical_fov_length_m(self, distance_m: float) -> float:
        """Height of the visible strip (m) at ``distance_m`` in front of the camera."""
        return distance_m * self.height / self.fy

    def in_image(self, pixels: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Whether pixels lie inside the image, at least ``margin_px`` from the border.

        Args:
            pixels: (..., 2) pixel coordinates (u, v). NaN counts as outside.

        Returns:
            (...) boolean array.
        """
        pixels = np.asarray(pixels, dtype=float)
        u, v = pixels[..., 0], pixels[..., 1]
        with np.errstate(invalid="ignore"):
            return (
                (u >= margin_px - 0.5)
                & (u <= self.width - 0.5 - margin_px)
                & (v >= margin_px - 0.5)
                & (v <= self.height - 0.5 - margin_px)
            )


def check_pose(T: np.ndarray, name: str = "T_world_camera") -> np.ndarray:
    """Validate a (4, 4) rigid transform and return it as a float array.

    Raises:
        ValueError: wrong shape, non-finite values, or a rotation block that is not orthonormal.
    """
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {T.shape}")
    if not np.isfinite(T).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    R = T[:3, :3]
    # np.allclose(R R^T, I, atol=1e-6) and det(R) > 0, written out: this runs for every frame.
    if (np.abs(R @ R.T - _IDENTITY3) > _ORTHONORMAL_TOLERANCE).any() or _det3(R) < 0:
        raise ValueError(f"{name} rotation block is not a proper rotation matrix")
    if (np.abs(T[3] - _LAST_ROW) > _LAST_ROW_TOLERANCE).any():
        raise ValueError(f"{name} last row must be [0, 0, 0, 1]")
    return T


_IDENTITY3 = np.eye(3)
# np.allclose's tolerance (atol + rtol |b|) against the identity with atol 1e-6, rtol 1e-5.
_ORTHONORMAL_TOLERANCE = 1e-6 + 1e-5 * _IDENTITY3
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_LAST_ROW_TOLERANCE = 1e-8 + 1e-5 * _LAST_ROW  # np.allclose's defaults


def _det3(R: np.ndarray) -> float:
    """Determinant of a (3, 3) matrix (the triple product of its rows)."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform."""
    R, t = T[:3, :3], T[:3, 3]
    T_inv = np.eye(4)
    T_inv[:3, :3] = R.T
    T_inv[:3, 3] = -R.T @ t
    return T_inv


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points."""
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


def projection_matrix(intrinsics: CameraIntrinsics, T_world_camera: np.ndarray) -> np.ndarray:
    """(3, 4) world-to-image matrix ``P = K [R | t]`` with ``[R | t] = inv(T_world_camera)``."""
    T_camera_world = invert_pose(np.asarray(T_world_camera, dtype=float))
    return intrinsics.K @ T_camera_world[:3, :]


def project_points(
    points_world: np.ndarray, T_world_camera: np.ndarray, intrinsics: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into the image.

    Args:
        points_world: (N, 3) points in metres, world frame.
        T_world_camera: (4, 4) camera pose.
        intrinsics: Camera intrinsics.

    Returns:
        pixels: (N, 2) pixel coordinates (u, v); NaN for points at or behind the camera.
        depth_m: (N,) z coordinate in the camera frame, metres.
    """
    p_cam = transform_points(invert_pose(np.asarray(T_world_camera, float)), points_world)
    z = p_cam[:, 2]
    pixels = np.full((len(p_cam), 2), np.nan)
    front = z > 1e-9
    pixels[front, 0] = intrinsics.fx * p_cam[front, 0] / z[front] + intrinsics.cx
    pixels[front, 1] = intrinsics.fy * p_cam[front, 1] / z[front] + intrinsics.cy
    return pixels, z


def pixel_rays_camera(pixels: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Unit viewing rays in the camera frame for (N, 2) pixels -> (N, 3)."""
    pixels = np.asarray(pixels, dtype=float)
    x = (pixels[:, 0] - intrinsics.cx) / intrinsics.fx
    y = (pixels[:, 1] - intrinsics.cy) / intrinsics.fy
    rays = np.stack([x, y, np.ones_like(x)], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def unproject_pixels(
    pixels: np.ndarray,
    depth_m: np.ndarray,
    T_world_camera: np.ndarray,
    intrinsics: CameraIntrinsics,
) -> np.ndarray:
    """World points for (N, 2) pixels at (N,) camera-frame depths z (metres) -> (N, 3)."""
    pixels = np.asarray(pixels, dtype=float)
    depth_m = np.asarray(depth_m, dtype=float)
    x = (pixels[:, 0] - intrinsics.cx) / intrinsics.fx * depth_m
    y = (pixels[:, 1] - intrinsics.cy) / intrinsics.fy * depth_m
    p_cam = np.stack([x, y, depth_m], axis=1)
    return transform_points(np.asarray(T_world_camera, float), p_cam)
