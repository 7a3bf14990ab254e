"""The eye-in-hand camera's geometry: pinhole intrinsics (:class:`CameraSpec`), pose checks and
``look_at``; no rendering (that is ``branch_gym/sim/scene/camera.py``).

Conventions (the same as ``recon/camera.py``, which this module must not import):

* Camera frame is OpenCV's: x right, y down, z forward along the optical axis.
* Pixel ``(u, v)`` = (column, row); the centre of the top-left pixel is (0, 0).
* ``T_world_camera`` is a (4, 4) transform with ``p_world = T_world_camera @ p_camera``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from branch_gym.sim.validation import require_finite

# Authors' simulated camera (reference.md, "Simulated world"): 320x240, 42 deg horizontal FoV.
DEFAULT_WIDTH_PX = 320
DEFAULT_HEIGHT_PX = 240
DEFAULT_HFOV_DEG = 42.0
DEFAULT_FOCAL_PX = (DEFAULT_WIDTH_PX / 2.0) / math.tan(math.radians(DEFAULT_HFOV_DEG) / 2.0)
# Clip planes (our choice): branches come no closer than a few cm; the backdrop is a few m away.
DEFAULT_NEAR_M = 0.01
DEFAULT_FAR_M = 10.0
_ROTATION_TOLERANCE = 1e-6  # on R R^T - I entries
_IDENTITY_3 = np.eye(3)
_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class CameraSpec:
    """Pinhole camera without distortion, plus the renderer's clip planes.

    Attributes:
        width: Image width in pixels.
        height: Image height in pixels.
        fx: Focal length along u in pixels (default: 42 deg HFOV at 320 px, ~416.8).
        fy: Focal length along v in pixels.
        cx: Principal point u in pixels (pixel centres at integers).
        cy: Principal point v in pixels.
        near_m: Near clip distance along the optical axis, metres.
        far_m: Far clip distance along the optical axis, metres.
    """

    width: int = DEFAULT_WIDTH_PX
    height: int = DEFAULT_HEIGHT_PX
    fx: float = DEFAULT_FOCAL_PX
    fy: float = DEFAULT_FOCAL_PX
    cx: float = DEFAULT_WIDTH_PX / 2.0
    cy: float = DEFAULT_HEIGHT_PX / 2.0
    near_m: float = DEFAULT_NEAR_M
    far_m: float = DEFAULT_FAR_M

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if int(value) != value or value <= 0:
                raise ValueError(f"{name} must be a positive integer, got {value}")
        require_finite(self, "fx", "fy", "cx", "cy", "near_m", "far_m")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"fx and fy must be positive, got fx={self.fx}, fy={self.fy}")
        if not 0 < self.near_m < self.far_m:
            raise ValueError(
                f"need 0 < near_m < far_m, got near_m={self.near_m}, far_m={self.far_m}"
            )

    @classmethod
    def from_hfov(
        cls,
        width: int,
        height: int,
        hfov_deg: float,
        near_m: float = DEFAULT_NEAR_M,
        far_m: float = DEFAULT_FAR_M,
    ) -> CameraSpec:
        """Square pixels from the horizontal field of view; principal point (width/2, height/2)."""
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        focal = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0, near_m, far_m)

    def scaled(self, factor: float) -> CameraSpec:
        """The same camera at ``factor`` x the resolution, the image's top-left edge kept.

        A pixel edge at u of this camera lies at ``factor * u`` of the result, so a principal
        point moves to ``factor * (c + 1/2) - 1/2``: with ``factor = 1 / s`` pixel i covers this
        camera's pixels ``s i .. s i + s - 1`` (binning; a last partial bin is dropped: the size
        is floored to whole pixels), with ``factor = k`` each pixel splits into k x k (a sensor
        of k times the resolution).

        Raises:
            ValueError: ``factor`` not positive, or no whole pixel left.
        """
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"CameraSpec.scaled: factor must be positive, got {factor!r}")
        width, height = (math.floor(side * factor + 1e-9) for side in (self.width, self.height))
        if width < 1 or height < 1:
            raise ValueError(
                f"CameraSpec.scaled: {self.width}x{self.height} times {factor} is empty"
            )
        return CameraSpec(
            width=width,
            height=height,
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=factor * (self.cx + 0.5) - 0.5,
            cy=factor * (self.cy + 0.5) - 0.5,
            near_m=self.near_m,
            far_m=self.far_m,
        )

    @property
    def K(self) -> np.ndarray:
        """(3, 3) calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(
        self, points_world: np.ndarray, T_world_camera: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pinhole projection.

        Args:
            points_world: (N, 3) points in metres, world frame.
            T_world_camera: (4, 4) camera pose.

        Returns:
            pixels (N, 2) as (u, v), NaN at or behind the camera; depth_m (N,) camera-frame z.
        """
        T_camera_world = np.linalg.inv(check_pose(T_world_camera))
        p_camera = (
            np.asarray(points_world, float) @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
        )
        z = p_camera[:, 2]
        pixels = np.full((len(z), 2), np.nan)
        front = z > 0
        pixels[front] = p_camera[front, :2] / z[front, None] * [self.fx, self.fy] + [
            self.cx,
            self.cy,
        ]
        return pixels, z


def check_pose(T_world_camera: np.ndarray) -> np.ndarray:
    """Validate a (4, 4) rigid transform; returns it as a float array.

    Raises:
        ValueError: wrong shape, non-finite entries, or not a proper rotation.
    """
    T = np.asarray(T_world_camera, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"T_world_camera must have shape (4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError("T_world_camera contains NaN or infinite values")
    R = T[:3, :3]
    # Plain max/abs: np.allclose costs ~40 us, and this runs twice per frame.
    if np.abs(R @ R.T - _IDENTITY_3).max() > _ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise ValueError("T_world_camera rotation block is not a proper rotation")
    if np.abs(T[3] - _HOMOGENEOUS_ROW).max() > _ROTATION_TOLERANCE:
        raise ValueError("T_world_camera last row must be [0, 0, 0, 1]")
    return T


@functools.lru_cache(maxsize=8)
def pixel_grid(spec: CameraSpec) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates as broadcastable float32 arrays: u (1, W) and v (H, 1) (cached)."""
    u = np.arange(spec.width, dtype=np.float32)[None, :]
    v = np.arange(spec.height, dtype=np.float32)[:, None]
    u.flags.writeable = False
    v.flags.writeable = False
    return u, v


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) T_world_camera at ``eye`` with the optical axis (+z) towards ``target``.

    The image's "up" (-y) is as close to ``up`` (world) as possible.

    Raises:
        ValueError: ``eye`` equals ``target``, or the view direction is parallel to ``up``.
    """
    eye, target, up = (np.asarray(a, dtype=float) for a in (eye, target, up))
    forward = target - eye
    if np.linalg.norm(forward) < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("look_at: view direction is parallel to up")
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)
    T[:3, 3] = eye
    return T
