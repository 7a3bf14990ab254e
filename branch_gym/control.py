"""The primary-branch following controller (paper section V).

``v = grad + k_u (u - w/2) + k_z (z - z_target)``, scaled to the set speed: ``(u, v)`` is the
projected primary point closest to image row h/2, ``z`` its camera depth and ``grad`` the
centerline tangent there (pointing up the image). Errors are normalised (reference.md: the
authors' gains k_u = k_z = 1 act on normalised errors). Before any model exists (or when none of
it is in view) the camera moves straight up. A small orientation term keeps the camera level
(image up = world up), which the paper's scan assumes and which numeric integration would drift.

Rotation (paper section V) is motion too: :class:`OrbitMove` turns the camera on a circle about the
world-vertical axis through the followed branch point, at the set speed, one control step at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from branch_gym.sim.robot.motion import orbit_camera_twist
from branch_gym.sim.validation import require_non_negative, require_positive
from recon.camera import CameraIntrinsics
from recon.model import BranchModel

WORLD_UP = np.array([0.0, 0.0, 1.0])
# Target angles closer than this to the current one are no move (deg; our choice: well below the
# paper's smallest rotation, 22.5 deg, and above the drift of the orbit integration).
ROTATION_TOLERANCE_DEG = 0.5
# Smallest orbit radius (m): guards the yaw rate when the camera sits on the pivot axis.
_MIN_ORBIT_RADIUS_M = 1e-3
# Points at most this far in front of the camera do not project (m; recon.camera.project_points).
_FRONT_DEPTH_M = 1e-9
# Norms below this are treated as zero when normalising a direction (guards a division).
_MIN_NORM = 1e-12
# An orbit is complete when less than this is left to turn (rad).
_ORBIT_DONE_RAD = 1e-6


@dataclass(frozen=True)
class FollowControllerConfig:
    """Gains and set points.

    Attributes:
        speed_mps: Camera speed (reference.md: 2.5 cm/s in the authors' simulator).
        k_u: Gain on the horizontal pixel error, normalised by w/2 (authors: 1).
        k_z: Gain on the depth error, normalised by z_target (authors: 1).
        z_target_m: Camera-to-branch distance (paper V: 0.20 m).
        k_level_per_s: Gain (1/s) of the term that keeps the image upright; our choice: corrects
            a small tilt within ~1 s, far slower than the motion it accompanies.
    """

    speed_mps: float = 0.025
    k_u: float = 1.0
    k_z: float = 1.0
    z_target_m: float = 0.20
    k_level_per_s: float = 1.0

    def __post_init__(self) -> None:
        require_non_negative(self, "k_u", "k_z", "k_level_per_s")
        require_positive(self, "speed_mps", "z_target_m")


@dataclass
class FollowCommand:
    """One controller output.

    Attributes:
        twist_camera: (6,) [v (m/s), w (rad/s)] in the camera frame.
        look_at_world: (3,) the followed primary point p (world), or None without a model in view.
        pixel_error: Normalised horizontal error (u - w/2) / (w/2) (0 without a model).
        depth_error: Normalised depth error (z - z_target) / z_target (0 without a model).
    """

    twist_camera: np.ndarray
    look_at_world: np.ndarray | None
    pixel_error: float = 0.0
    depth_error: float = 0.0


class PrimaryBranchController:
    """Follows the 3D primary branch model up the tree at a set distance, centred in the image."""

    def __init__(
        self,
        config: FollowControllerConfig | None = None,
        intrinsics: CameraIntrinsics | None = None,
    ) -> None:
        self.config = config or FollowControllerConfig()
        self.intrinsics = intrinsics or CameraIntrinsics.from_fov()
        intr = self.intrinsics  # the projection's constants, as (u, v) pairs
        self._focal_px = np.array([intr.fx, intr.fy], dtype=float)
        self._center_px = np.array([intr.cx, intr.cy], dtype=float)
        self._last_pixel = np.array([intr.width - 1, intr.height - 1], dtype=float)
        self._middle_row_px = intr.height / 2.0

    def look_at_point(
        self, primary: BranchModel | None, T_world_camera: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, int] | None:
        """Model point projected nearest row h/2: (pixel (2,), camera-frame point (3,), index)."""
        found = self._look_at(primary, T_world_camera)
        if found is None:
            return None
        pixel, points_camera, index = found
        return pixel, points_camera[index].copy(), index

    def _look_at(
        self, primary: BranchModel | None, T_world_camera: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(pixel (2,), all model points in the camera frame (N, 3), index) or None.

        One transform of the model serves the projection, the look-at point and the tangent
        (:func:`recon.camera.project_points` and ``transform_points`` of the same pose, fused).
        """
        if primary is None or len(primary.points) < 2:
            return None
        R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
        points_camera = primary.points @ R - R.T @ t
        candidates = np.flatnonzero(points_camera[:, 2] > _FRONT_DEPTH_M)
        if not candidates.size:
            return None
        front = points_camera[candidates]
        pixels = front[:, :2] * self._focal_px / front[:, 2:] + self._center_px  # (M, 2) u, v
        inside = (pixels >= 0.0) & (pixels <= self._last_pixel)
        in_view = np.flatnonzero(inside[:, 0] & inside[:, 1])
        if not in_view.size:
            return None
        best = in_view[np.argmin(np.abs(pixels[in_view, 1] - self._middle_row_px))]
        return pixels[best], points_camera, int(candidates[best])

    def command(self, primary: BranchModel | None, T_world_camera: np.ndarray) -> FollowCommand:
        """The camera twist for this control step."""
        cfg = self.config
        R = T_world_camera[:3, :3]
        w_camera = R.T @ self._level_correction(R)
        found = self._look_at(primary, T_world_camera)
        if found is None:
            v_camera = R.T @ WORLD_UP * cfg.speed_mps
            return FollowCommand(np.concatenate([v_camera, w_camera]), None)
        pixel, points_camera, index = found
        grad = (
            points_camera[min(index + 1, len(points_camera) - 1)] - points_camera[max(index - 1, 0)]
        )
        if grad[1] > 0:  # point up the image (camera -y)
            grad = -grad
        grad /= max(math.sqrt(float(grad @ grad)), _MIN_NORM)
        pixel_error = (pixel[0] - self.intrinsics.width / 2.0) / (self.intrinsics.width / 2.0)
        depth_error = (points_camera[index, 2] - cfg.z_target_m) / cfg.z_target_m
        v = grad.copy()
        v[0] += cfg.k_u * pixel_error
        v[2] += cfg.k_z * depth_error
        v_camera = v / max(math.sqrt(float(v @ v)), _MIN_NORM) * cfg.speed_mps
        look_at = primary.points[index].copy()
        return FollowCommand(
            np.concatenate([v_camera, w_camera]), look_at, float(pixel_error), float(depth_error)
        )

    def _level_correction(self, R_world_camera: np.ndarray) -> np.ndarray:
        """World angular velocity turning the image's down axis (camera y) onto world -z."""
        down = R_world_camera[:, 1]
        # cross(down, -WORLD_UP), written out: the z component is 0.
        axis = np.array([-down[1], down[0], 0.0])
        return self.config.k_level_per_s * axis


def heading_rad(T_world_camera: np.ndarray) -> float:
    """Yaw of the optical axis about world z (rad), 0 along +y (the home view direction)."""
    axis = T_world_camera[:3, 2]
    return math.atan2(-axis[0], axis[1])


class OrbitMove:
    """One rotation: the camera orbits the world-vertical axis through the followed branch point.

    The pivot is the primary model point the controller looks at (or, without a model in view,
    the point ``z_target`` ahead on the optical axis), at camera height. The yaw rate makes the
    camera travel at ``speed_mps`` along the circle. Drive it with :meth:`command` (the twist and
    duration of the next control step) and :meth:`advance` (after the robot moved).

    Args:
        controller: The follow controller (look-at point, z_target).
        primary: The 3D primary model, or None.
        T_world_camera: (4, 4) camera pose when the rotation starts.
        turn_deg: Signed rotation still to do (deg): target angle minus current angle.
        speed_mps: Camera speed along the circle (m/s).
    """

    def __init__(
        self,
        controller: PrimaryBranchController,
        primary: BranchModel | None,
        T_world_camera: np.ndarray,
        turn_deg: float,
        speed_mps: float,
    ) -> None:
        found = controller.look_at_point(primary, T_world_camera)
        if found is not None:
            pivot = primary.points[found[2]].copy()
        else:  # no model in view: pivot z_target ahead on the optical axis
            pivot = T_world_camera[:3, 3] + T_world_camera[:3, 2] * controller.config.z_target_m
        pivot[2] = T_world_camera[2, 3]
        self.pivot_world_m = pivot
        radius_m = max(
            float(np.linalg.norm(T_world_camera[:2, 3] - pivot[:2])), _MIN_ORBIT_RADIUS_M
        )
        self.remaining_rad = math.radians(turn_deg)
        self.yaw_rate_radps = math.copysign(speed_mps / radius_m, self.remaining_rad)
        self._heading_rad = heading_rad(T_world_camera)

    @property
    def finished(self) -> bool:
        return abs(self.remaining_rad) <= _ORBIT_DONE_RAD

    def command(self, T_world_camera: np.ndarray, control_dt_s: float) -> tuple[np.ndarray, float]:
        """(6,) camera twist and the duration (s) of the next step: at most ``control_dt_s``."""
        dt_s = min(control_dt_s, abs(self.remaining_rad / self.yaw_rate_radps))
        return orbit_camera_twist(T_world_camera, self.pivot_world_m, self.yaw_rate_radps), dt_s

    def advance(self, T_world_camera: np.ndarray) -> float:
        """Account for the robot's move; returns the yaw actually turned (deg)."""
        new_heading = heading_rad(T_world_camera)
        turned = math.remainder(new_heading - self._heading_rad, math.tau)
        self._heading_rad = new_heading
        self.remaining_rad -= turned
        return math.degrees(turned)
